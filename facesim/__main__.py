"""``python -m facesim``: the ``facesim`` command."""

import sys

from facesim.cli import main

sys.exit(main())
