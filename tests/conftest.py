"""What every test's code sees of the machine: the design cache is the clone's build/test-design-cache,
not the user's ~/.cache/rodgains, so results and run time never depend on earlier runs of rodctl on
this machine or on HOME. Set here, at import, so the rodctl subprocesses the tests start inherit it;
the tests of the cache itself set their own folder (tests/test_design_cache.py).

What runs is chosen on the command line only: --full-reference adds the tests marked full_reference.

The order: the slowest test files first (SLOWEST_FIRST), the others as collected. .ci/run gives each file to
one worker in that order (`--dist loadfile --no-loadscope-reorder`), so the longest file starts at once and
the others fill the second worker around it, rather than a long file starting last and running alone."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ["RODGAINS_CACHE_DIR"] = str(Path(__file__).resolve().parents[1] / "build" / "test-design-cache")


def pytest_addoption(parser):
    parser.addoption("--full-reference", action="store_true",
                     help="also run the tests marked full_reference (DER references on the Python model: minutes)")


def pytest_configure(config):
    config.addinivalue_line("markers", "full_reference: integrates a reference on the Python model (minutes); "
                                       "runs only with --full-reference")


# longest first, by each file's test time from a fresh clone (`pytest --durations=0`)
SLOWEST_FIRST = ("test_identify.py", "test_robust_design.py", "test_check.py", "test_docs_site.py", "test_track.py",
                 "test_host_log.py", "test_robustness_matrix.py", "test_bad_inputs.py")


def pytest_collection_modifyitems(config, items):
    """The slowest files first (a stable sort: each file's own order stays). A long test is chosen on the
    command line, where the run shows it, never by the environment."""
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
    if config.getoption("--full-reference"):
        return
    skip = pytest.mark.skip(reason="minutes on the Python model: run with --full-reference")
    for item in items:
        if "full_reference" in item.keywords:
            item.add_marker(skip)
