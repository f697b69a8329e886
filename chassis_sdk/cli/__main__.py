"""``python -m chassis_sdk.cli``: the same as the ``chassis-sdk`` command."""

import contextlib
import sys

from . import main

with contextlib.suppress(KeyboardInterrupt):
    sys.exit(main())
