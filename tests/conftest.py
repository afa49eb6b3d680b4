"""What every test's code sees of the machine: the design cache is the clone's build/test-design-cache,
not the user's ~/.cache/rodgains, so results and run time never depend on earlier runs of rodctl on
this machine or on HOME. Set here, at import, so the rodctl subprocesses the tests start inherit it;
the tests of the cache itself set their own folder (tests/test_design_cache.py)."""

from __future__ import annotations

import os
from pathlib import Path

os.environ["RODGAINS_CACHE_DIR"] = str(Path(__file__).resolve().parents[1] / "build" / "test-design-cache")
