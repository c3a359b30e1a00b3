"""``python -m climbd.daemon.cli``: the ``climbd`` command."""

import sys

from climbd.daemon.cli.main import main

sys.exit(main())
