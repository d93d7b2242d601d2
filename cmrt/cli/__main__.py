"""``python -m cmrt.cli``: the ``cmrt`` command."""

import sys

from cmrt.cli.commands import main

sys.exit(main())
