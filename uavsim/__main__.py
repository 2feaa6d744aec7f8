"""``python -m uavsim``: the ``uavsim`` command."""

import sys

from uavsim.cli.main import main

sys.exit(main())
