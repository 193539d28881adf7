"""`python -m gazehdr`: the same command line as the `gazehdr` script."""

import sys

from gazehdr.cli import main

sys.exit(main())
