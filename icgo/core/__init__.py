"""The ground floor every layer may import: the error hierarchy and the config helpers.

Nothing here imports another part of icgo.
"""
