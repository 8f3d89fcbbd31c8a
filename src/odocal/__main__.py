"""``python -m odocal``: the ``odocal`` command."""

from odocal.cli import run

if __name__ == "__main__":      # (not when a spawned helper imports this module as its main)
    run()
