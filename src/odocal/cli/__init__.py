"""The ``odocal`` command: argument parsing, progress, one-line errors and exit codes.

Every command calls a library function; nothing here computes. May import everything.
"""

from __future__ import annotations


def _leave_ctrl_c_to_the_parent() -> None:
    """In a process the ``odocal`` program starts with multiprocessing's ``spawn`` (a Dask
    worker of ``odocal fleet``): ignore Ctrl-C from its first moment.

    Ctrl-C from a terminal goes to the whole process group: a worker still importing its
    libraries would die of it printing a traceback of its own (and the program stops its
    workers itself). Such a process imports the program's main script, and so this package,
    before anything heavy (multiprocessing's ``_inheriting`` says it is being set up); the
    ignored signal stays ignored in it and in what it starts."""
    import sys

    process = sys.modules.get("multiprocessing.process")
    if process is not None and getattr(process.current_process(), "_inheriting", False):
        import signal

        signal.signal(signal.SIGINT, signal.SIG_IGN)


_leave_ctrl_c_to_the_parent()


def run() -> None:
    """The ``odocal`` program (its console entry point and ``python -m odocal``).

    Ctrl-C is handled from the first moment: the handler is installed before the command line
    module and what it imports load (:mod:`odocal.cli.interrupt`).
    """
    import os
    import sys

    # odocal's matrices are small and its parallel work runs in processes: one BLAS thread
    # each (unless the user says otherwise), or the BLAS pools of the processes spin against
    # each other on a busy machine (a clock-offset search took 7 s instead of 1). Set before
    # numpy loads its BLAS.
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")

    from odocal.cli import interrupt

    interrupt.install()
    try:
        from odocal.cli.main import main
    except KeyboardInterrupt:            # before the command line is parsed: its first word
        word = sys.argv[1] if len(sys.argv) > 1 else ""
        named = word.replace("-", "").isalnum() and word.islower()
        interrupt.leave(f"odocal {word}" if named else "odocal")
    sys.exit(main())
