"""``python -m seal`` runs the command line."""

import sys

from seal.cli import main

sys.exit(main())
