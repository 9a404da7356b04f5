"""``python -m sltwin ...``: the ``calib`` command."""
import sys

from .cli import main

sys.exit(main())
