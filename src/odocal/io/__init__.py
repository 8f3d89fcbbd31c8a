"""Outside formats in, one in-memory :class:`~odocal.data.drive.Drive` out, and the drive
format back.

May import: :mod:`odocal.data`, :mod:`odocal.model` (the parameter layout), the leaves
(:mod:`odocal.settings`, :mod:`odocal.errors`, :mod:`odocal.arrays`); nothing above.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from odocal.io.drivefile import load_drive, save_drive

__all__ = ["load_drive", "save_drive"]


def __getattr__(name: str) -> Any:
    # pyarrow is loaded only when a drive file is read or written
    if name in __all__:
        from odocal.io import drivefile

        return getattr(drivefile, name)
    raise AttributeError(f"module 'odocal.io' has no attribute {name!r}")
