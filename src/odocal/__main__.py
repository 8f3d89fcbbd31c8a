"""``python -m odocal``: the ``odocal`` command."""

import sys

from odocal.cli.main import main

sys.exit(main())
