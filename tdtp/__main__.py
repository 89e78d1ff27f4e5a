"""``python -m tdtp``: the same as the ``tdtp`` command."""

import sys

from tdtp.cli.main import main

sys.exit(main())
