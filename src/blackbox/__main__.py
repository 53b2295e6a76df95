"""``python -m blackbox``."""

import sys

from blackbox.cli import main

sys.exit(main())
