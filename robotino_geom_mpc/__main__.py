"""`python -m robotino_geom_mpc` is the `robotino-geom-mpc` command."""

import sys

from robotino_geom_mpc.cli import main

sys.exit(main())
