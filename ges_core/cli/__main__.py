"""``python -m ges_core.cli``."""

import sys

from ges_core.cli import main

sys.exit(main())
