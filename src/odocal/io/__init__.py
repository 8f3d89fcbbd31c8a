"""Outside formats in, one in-memory :class:`~odocal.drive.Drive` out, and the drive format back."""

from odocal.io.drivefile import load_drive, save_drive

__all__ = ["load_drive", "save_drive"]
