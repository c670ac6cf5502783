"""`python -m mjx_push.cli` is `mjx-push`."""

import sys

from mjx_push.cli import main

sys.exit(main())
