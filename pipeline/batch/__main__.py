"""`python -m pipeline.batch PLAN --out DIR` = `platolidar batch PLAN --out DIR`."""

import sys

from .cli import main

sys.exit(main())
