"""`python -m forcdecode ...`: the same entry as the `forcdecode` command."""

import sys

from .cli import main

sys.exit(main())
