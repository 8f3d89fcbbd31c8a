"""The ``odocal`` command line: a thin shell around the library.

One rule for exit codes: 0 done (including valid data that identify nothing); 1 bad input,
settings or output (one line on stderr, no traceback); 2 a command line that cannot run as
typed (an unknown or misspelt option, a value out of its range, options that do not go
together); 3 the calibration ran but failed (refused by the checks, the solver, the quality
gate); 4 an internal error (a bug: rerun with -v for the traceback and report it); 130
interrupted.

The commands live in one module per family (:mod:`odocal.cli.simulation`,
:mod:`~odocal.cli.calibration`, :mod:`~odocal.cli.checking`, :mod:`~odocal.cli.online`,
:mod:`~odocal.cli.fleet`), the parser in :mod:`odocal.cli.parser`.
"""

from __future__ import annotations

import argparse
import gc
import logging
import sys
from collections.abc import Callable, Sequence

from odocal.cli import interrupt
from odocal.cli.common import (
    EXIT_BUG,
    EXIT_ERROR,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    UsageError,
)
from odocal.cli.parser import build_parser
from odocal.errors import OdocalError, shown

# numpy, scipy and numba load only in the commands that compute: --help and --version stay fast.

__all__ = ["EXIT_BUG", "EXIT_ERROR", "EXIT_FAILED", "EXIT_INTERRUPTED", "EXIT_OK",
           "EXIT_USAGE", "build_parser", "main"]


def _configure_logging(verbose: int, quiet: bool) -> None:
    level = logging.ERROR if quiet else (logging.WARNING if verbose == 0 else
                                         logging.INFO if verbose == 1 else logging.DEBUG)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    from odocal.redaction import Redacting

    for handler in logging.getLogger().handlers:       # no URL query or secret in any line
        if type(handler) is logging.StreamHandler and not isinstance(handler.formatter,
                                                                      Redacting):
            handler.setFormatter(Redacting(handler.formatter))
    if verbose == 0:
        # warnings are printed in the summary; keep the log for -v
        logging.getLogger("odocal").setLevel(logging.ERROR)


def _causes(exc: BaseException) -> list[BaseException]:
    """What led to an error, outermost first (``raise ... from err`` and errors raised while
    handling another), without repeats."""
    out: list[BaseException] = []
    cause = exc.__cause__ or (None if exc.__suppress_context__ else exc.__context__)
    while cause is not None and cause not in out and len(out) < 10:
        out.append(cause)
        cause = cause.__cause__ or (None if cause.__suppress_context__ else cause.__context__)
    return out


def _parse(words: list[str]) -> argparse.Namespace:
    """The parsed command line; ``odocal ros2 ... --ros-args ...`` hands everything from
    ``--ros-args`` on to ROS 2 as it is."""
    ros_args: list[str] = []
    if words[:1] == ["ros2"] and "--ros-args" in words:
        cut = words.index("--ros-args")
        ros_args, words = words[cut:], words[:cut]
    return build_parser().parse_args(words, argparse.Namespace(ros_args=tuple(ros_args)))


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None:
        interrupt.install()           # the program itself: Ctrl-C remembered (cli/interrupt.py)
    try:
        args = _parse(list(sys.argv[1:] if argv is None else argv))
    except KeyboardInterrupt:
        return _interrupted("odocal", argv)
    _configure_logging(args.verbose, args.quiet)
    command = f"odocal {args.command}"
    if argv is None and args.command not in _ENDED_BY_CTRL_C:
        interrupt.watch(command)      # Ctrl-C leaves within seconds, whatever is waited for
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        code = func(args)
        if _swallowed(args):          # an interrupt some library swallowed on the way
            return _interrupted(command, argv)
        return code
    except UsageError as exc:         # options that do not go together: as argparse says it
        sys.stderr.write(f"{command}: error: {shown(exc, 2000)}\n")
        return EXIT_USAGE
    except OdocalError as exc:
        if _swallowed(args):
            return _interrupted(command, argv)
        sys.stderr.write(f"{command}: error: {shown(exc, 2000)}\n")
        if args.verbose:
            for cause in _causes(exc):
                sys.stderr.write(f"  caused by {type(cause).__name__}: {shown(cause, 2000)}\n")
        return EXIT_ERROR
    except KeyboardInterrupt:
        return _interrupted(command, argv)
    except BrokenPipeError:  # the reader went away (| head): stop quietly
        sys.stderr.close()
        return EXIT_OK
    except OSError as exc:   # the machine said no (a name too long, no space, no permission)
        if _swallowed(args):
            return _interrupted(command, argv)
        if args.verbose:
            raise
        where = f" '{shown(exc.filename)}'" if exc.filename else ""
        sys.stderr.write(f"{command}: error: cannot use{where}: "
                         f"{shown(exc.strerror or exc)}\n")
        return EXIT_ERROR
    except MemoryError:
        sys.stderr.write(f"{command}: error: out of memory: the settings ask for more than "
                         "this machine has (docs: input limits)\n")
        return EXIT_ERROR
    except Exception as exc:  # a bug: say so in one line, with the traceback on request
        if _swallowed(args):          # (or what an interrupt left behind: a half-done import)
            return _interrupted(command, argv)
        if args.verbose:
            raise
        sys.stderr.write(f"{command}: internal error: {type(exc).__name__}: "
                         f"{shown(exc, 300)} (rerun with -v for the traceback)\n")
        return EXIT_BUG
    finally:
        if argv is None:
            # the program ends here: what it made needs no collecting on the way out (the
            # interpreter's last collection took 0.2 s after a one-hour calibration)
            gc.freeze()


#: Commands whose normal end is Ctrl-C (a node that spins until stopped): they catch it
#: themselves and say how they ended.
_ENDED_BY_CTRL_C = frozenset({"ros2"})


def _swallowed(args: argparse.Namespace) -> bool:
    """Whether Ctrl-C was pressed during a command that does not end on it."""
    return interrupt.interrupted() and args.command not in _ENDED_BY_CTRL_C


def _interrupted(command: str, argv: Sequence[str] | None) -> int:
    """Ctrl-C: one line, exit 130. The program itself (not a caller's ``main([...])``) has
    stopped and cleaned up its work (pools terminated, temporary results removed) and leaves
    now rather than wait in exit handlers for the threads of a broken pool."""
    if argv is None:
        interrupt.leave(command)
    sys.stderr.write(f"{command}: interrupted\n")
    sys.stderr.flush()
    sys.stdout.flush()
    return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
