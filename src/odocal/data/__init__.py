"""The in-memory drive and the ways it is cut: segments (METHOD 2).

Owns :class:`~odocal.data.drive.Drive` (checked on creation: units, limits, spikes) and the
identification and validation segments (:mod:`.segments`).

May import: :mod:`odocal.model` and the leaves (:mod:`odocal.errors`, :mod:`odocal.settings`,
:mod:`odocal.arrays`).
"""
