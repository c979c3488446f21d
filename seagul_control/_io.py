"""The former private name of :mod:`seagul_control.io`, kept for the modules that still import it.

Importing it gives the public module itself (the same object in ``sys.modules``), so a test that patches
``seagul_control._io`` patches the functions every caller uses.
"""

from __future__ import annotations

import sys

from seagul_control import io as _public
from seagul_control.io import *  # noqa: F403  (the names, for static checkers)

sys.modules[__name__] = _public
