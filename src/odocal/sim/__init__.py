"""Drives with known truth: the simulator, its noise profiles and the Cramér-Rao bound.

May import: :mod:`odocal.model`, :mod:`odocal.data` and the leaves.
"""
