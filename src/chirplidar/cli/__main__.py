"""``python -m chirplidar.cli``: the ``chirplidar`` command."""

import sys

from . import main

sys.exit(main())
