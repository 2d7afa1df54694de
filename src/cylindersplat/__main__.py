"""``python -m cylindersplat ...`` (also what ``torchrun -m cylindersplat train ...`` runs)."""

import sys

from .cli import main

sys.exit(main())
