"""``python -m pbdyn`` runs the pbdyn command."""

import sys

from pbdyn.cli import main

sys.exit(main())
