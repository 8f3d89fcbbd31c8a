"""``python -m odocal``: the ``odocal`` command."""

from odocal.cli import run

run()
