"""The version of odocal (a leaf: imported by anything that records it)."""

__version__ = "0.1.0"
