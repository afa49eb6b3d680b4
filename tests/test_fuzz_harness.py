"""The receive-path fuzz target (.ci/run fuzzes it for a bounded time) builds, runs its committed
seed corpus clean, and the corpus is what tests/fuzz/make_corpus.py writes."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_sil import header_path
from rodctl import paths

FUZZ = Path(__file__).parent / "fuzz"
sys.path.insert(0, str(FUZZ))


def test_committed_corpus_is_current():
    from make_corpus import seeds

    want = seeds()
    have = {p.name: p.read_bytes() for p in (FUZZ / "corpus").glob("seed_*")}
    assert have == want, "regenerate with: python tests/fuzz/make_corpus.py"


@pytest.mark.skipif(shutil.which("clang") is None, reason="clang not installed (.ci/run installs it)")
def test_fuzz_target_runs_the_seed_corpus_under_sanitizers(tmp_path):
    exe = tmp_path / "rx_fuzz"
    cmd = ["clang", "-std=c11", "-g", "-O1", "-Wall", "-Wextra", "-Wdouble-promotion", "-Werror",
           "-fsanitize=fuzzer,address,undefined", "-fno-sanitize-recover=all", f"-I{header_path().parent}",
           f"-I{paths.CORE_SRC}", str(FUZZ / "rx_device_fuzz.c"), *map(str, sorted(paths.CORE_SRC.glob("*.c"))),
           "-lm", "-o", str(exe)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0 and "fuzzer" in r.stderr and "cannot find" in r.stderr.lower():
        pytest.skip("no libFuzzer runtime (Debian: libclang-rt-14-dev, which .ci/run installs)")
    assert r.returncode == 0, r.stderr
    run = subprocess.run([str(exe), "-runs=0", str(FUZZ / "corpus")], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "runtime error" not in run.stderr
    # What libFuzzer read, and what it ran: every committed seed once, after the empty input it always tries first.
    committed = len([p for p in (FUZZ / "corpus").iterdir() if p.is_file()])
    loaded = re.search(r"^INFO: seed corpus: files: (\d+) ", run.stderr, re.M)
    done = re.search(r"^Done (\d+) runs in ", run.stderr, re.M)
    assert loaded and done, run.stderr[-3000:]
    assert (int(loaded[1]), int(done[1])) == (committed, committed + 1)
