"""Data and formats: the data contract (CSV + ``<name>.meta.json``) and circuitpython-mag-cal JSON recordings.

``recording`` reads, validates and writes contract recordings (one-line :class:`~icgo.core.errors.DataError`
naming the file, row and column) with ``schema`` (columns, keys, limits), ``checks`` and ``csv_text`` (the CSV
text's readers); ``mag_cal_bundled`` holds the bundled devices and ``mag_cal_json`` reads the JSON layouts.
``python -m icgo.io check FILE`` checks a file from the command line.
"""
