"""From raw streams to a drive: alignment, reference-pose fusion and sideslip (METHOD 7).

May import: :mod:`odocal.io`, :mod:`odocal.data`, :mod:`odocal.model`, the leaves
(:mod:`odocal.settings`, :mod:`odocal.errors`, :mod:`odocal.arrays`,
:mod:`odocal.correlation`); nothing above.
"""
