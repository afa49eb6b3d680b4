"""What every test's code sees of the machine: the design cache is the clone's build/test-design-cache,
not the user's ~/.cache/rodgains, so results and run time never depend on earlier runs of rodctl on
this machine or on HOME. Set here, at import, so the rodctl subprocesses the tests start inherit it;
the tests of the cache itself set their own folder (tests/test_design_cache.py). BLAS runs one thread,
as under `rodctl` (cli.one_blas_thread).

What runs is chosen on the command line only: --full-reference adds the tests marked full_reference."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from rodctl.cli import one_blas_thread

one_blas_thread()  # as `rodctl` does, for the code the tests run in this process
os.environ["RODGAINS_CACHE_DIR"] = str(Path(__file__).resolve().parents[1] / "build" / "test-design-cache")


def pytest_addoption(parser):
    parser.addoption("--full-reference", action="store_true",
                     help="also run the tests marked full_reference (DER references on the Python model: minutes)")


def pytest_configure(config):
    config.addinivalue_line("markers", "full_reference: integrates a reference on the Python model (minutes); "
                                       "runs only with --full-reference")


def pytest_collection_modifyitems(config, items):
    """A long test is chosen on the command line, where the run shows it, never by the environment."""
    if config.getoption("--full-reference"):
        return
    skip = pytest.mark.skip(reason="minutes on the Python model: run with --full-reference")
    for item in items:
        if "full_reference" in item.keywords:
            item.add_marker(skip)
