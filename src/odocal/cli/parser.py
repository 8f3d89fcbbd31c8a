"""The one parser of the ``odocal`` command: every command family registers its commands
here, and every usage error is one line with exit 2, naming what was typed and, for a
misspelt option or command, what was probably meant.

Light on purpose: building it imports no numpy (``odocal --help`` answers at once).
"""

from __future__ import annotations

import argparse
import difflib
import re
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

from odocal._version import __version__


def suggestion(word: str, known: Sequence[str]) -> str | None:
    """The known name closest to ``word`` (a misspelt option or command), or None."""
    option = word.split("=", 1)[0]
    close = difflib.get_close_matches(option, list(known), n=1, cutoff=0.6)
    return close[0] if close else None


class Parser(argparse.ArgumentParser):
    """argparse's parser, with "did you mean" for misspelt options and commands."""

    _words: Sequence[str] = ()

    def parse_known_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                         namespace: argparse.Namespace | None = None
                         ) -> tuple[argparse.Namespace, list[str]]:
        self._words = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def parse_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                   namespace: argparse.Namespace | None = None) -> argparse.Namespace:
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}"
                       + self._meant(extras, parsed))
        return parsed

    def _meant(self, extras: Sequence[str], parsed: argparse.Namespace) -> str:
        """`` (did you mean --datasheet?)`` for the first unknown option near a known one of
        the command that was typed."""
        known = self._options_of(parsed)
        for word in extras:
            if word.startswith("--"):
                near = suggestion(word, known)
                if near:
                    return f" (did you mean {near}?)"
        return ""

    def _options_of(self, parsed: argparse.Namespace) -> list[str]:
        parser: argparse.ArgumentParser = self
        for key in ("command", "fleet_command"):
            name = vars(parsed).get(key)
            sub = _subparsers(parser)
            if name is None or sub is None or name not in sub.choices:
                break
            parser = sub.choices[name]
        return [o for a in parser._actions for o in a.option_strings if o.startswith("--")]

    def error(self, message: str) -> NoReturn:
        match = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if match:
            choices = re.findall(r"'([^']*)'", match.group(2))
            near = suggestion(match.group(1), choices)
            if near:
                message += f" (did you mean {near}?)"
        elif message.startswith("the following arguments are required"):
            # a required option misspelt: the misspelling is why it is missing
            known = [o for a in self._actions for o in a.option_strings]
            for word in self._words:
                near = suggestion(word, known) if word.startswith("--") else None
                if near and word.split("=", 1)[0] not in known:
                    message += f"; {word.split('=', 1)[0]} is not an option (did you mean {near}?)"
                    break
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


def _subparsers(parser: argparse.ArgumentParser) -> Any:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    return None


def build_parser() -> Parser:
    """The parser of every command (each family adds its own: :mod:`odocal.cli.simulation`,
    :mod:`~odocal.cli.calibration`, :mod:`~odocal.cli.checking`, :mod:`~odocal.cli.online`,
    :mod:`~odocal.cli.fleet`)."""
    from odocal.cli import calibration, checking, fleet, online, simulation

    parser = Parser(prog="odocal",
                    description="Calibrate a vehicle's wheel-odometry model from logged drives.",
                    epilog="odocal COMMAND --help says more of each command.")
    parser.add_argument("--version", action="version", version=f"odocal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=Parser)
    simulation.add_parsers(sub)
    calibration.add_parsers(sub)
    checking.add_parsers(sub)
    online.add_parsers(sub)
    fleet.add_parsers(sub)
    return parser
