"""The ``odocal`` program with one library function whose clean-up never comes back after a
Ctrl-C, as a library's close can (Dask's client waits up to a minute for a scheduler that is
going away):

    python -m tests.cli.stuck MODULE:FUNCTION odocal-arguments...

The first call of ``MODULE.FUNCTION`` sends SIGINT to this process and, on the way out of the
interrupt, waits for ever; the program must still leave (exit 130, its one line).
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import threading
import time
from typing import Any


def main() -> None:
    target, *argv = sys.argv[1:]
    module_name, name = target.split(":")
    module = importlib.import_module(module_name)

    def stuck(*args: Any, **kwargs: Any) -> Any:
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(30.0)                     # the handler raises here
        finally:
            threading.Event().wait()             # a clean-up that never ends

    setattr(module, name, stuck)
    sys.argv = ["odocal", *argv]
    from odocal.cli import run

    run()


if __name__ == "__main__":
    main()
