"""``python -m rdd``."""

import sys

from rdd.cli import main

if __name__ == "__main__":
    sys.exit(main())
