"""``python -m stepterrain``: the ``stepterrain`` command (:func:`stepterrain.cli.main`), for environments whose
scripts folder is not on ``PATH``."""

import sys

from .cli import main

sys.exit(main())
