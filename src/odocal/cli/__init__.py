"""The ``odocal`` command: argument parsing, progress, one-line errors and exit codes.

Every command calls a library function; nothing here computes. May import everything.
"""

from __future__ import annotations


def run() -> None:
    """The ``odocal`` program (its console entry point and ``python -m odocal``).

    Ctrl-C is handled from the first moment: the handler is installed before the command line
    module and what it imports load (:mod:`odocal.cli.interrupt`).
    """
    import sys

    from odocal.cli import interrupt

    interrupt.install()
    try:
        from odocal.cli.main import main
    except KeyboardInterrupt:
        interrupt.leave("odocal")
    sys.exit(main())
