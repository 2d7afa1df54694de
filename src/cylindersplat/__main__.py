"""``python -m cylindersplat ...`` (also what ``torchrun -m cylindersplat train ...`` runs)."""

import sys

from .console import main  # first: Ctrl-C from here on ends in one line

sys.exit(main())
