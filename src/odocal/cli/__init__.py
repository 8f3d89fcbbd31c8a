"""The ``odocal`` command: argument parsing, progress, one-line errors and exit codes.

Every command calls a library function; nothing here computes. May import everything.
"""
