"""``python -m lead_s2r.cli``: the ``lead-s2r`` console script."""

import sys

from lead_s2r.cli import main

sys.exit(main())
