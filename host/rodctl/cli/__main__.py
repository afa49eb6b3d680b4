"""`python -m rodctl.cli` is `rodctl`."""

import sys

from rodctl.cli import main

sys.exit(main())
