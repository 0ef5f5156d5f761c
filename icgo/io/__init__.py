"""Data and formats: the data contract (CSV + ``<name>.meta.json``) and circuitpython-mag-cal JSON recordings.

``recording`` reads, validates and writes contract recordings (one-line :class:`~icgo.core.errors.DataError`
naming the file, row and column) and holds the bundled devices; ``mag_cal_json`` reads the JSON layouts.
``python -m icgo.io check FILE`` checks a file from the command line.
"""
