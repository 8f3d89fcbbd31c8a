"""The ``odocal`` program with one library function made to swallow a Ctrl-C, as some libraries
do (pyarrow asking whether pandas imports, a bare ``except:`` around an import, an at-fork
handler): the interrupt lands inside the call and is dropped there.

    python -m tests.cli.swallowing MODULE:FUNCTION odocal-arguments...

The first call of ``MODULE.FUNCTION`` sends SIGINT to this process, catches the
KeyboardInterrupt and goes on as if nothing was pressed; the program must still stop, and
publish nothing.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import time
from typing import Any


def main() -> None:
    target, *argv = sys.argv[1:]
    module_name, name = target.split(":")
    module = importlib.import_module(module_name)
    original = getattr(module, name)
    done = []

    def swallowing(*args: Any, **kwargs: Any) -> Any:
        if not done:
            done.append(True)
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(1.0)                  # the handler runs here, and is dropped
            except BaseException:
                pass
        return original(*args, **kwargs)

    setattr(module, name, swallowing)
    sys.argv = ["odocal", *argv]
    from odocal.cli import run

    run()


if __name__ == "__main__":
    main()
