"""``python -m tvcid``: the same as the ``tvcid`` command."""
import sys

from .cli import main

sys.exit(main())
