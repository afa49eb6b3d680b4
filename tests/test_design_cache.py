"""The robust refinement's on-disk cache (gains/rodgains/design_cache.py).

What a user notices: the second `rodctl` command that needs a robust design starts in a fraction
of a second instead of about 25 s, with the very same gains; a changed parameter is designed anew;
a broken or read-only cache never stops a design. The refinement itself is faked here (its result
is what the cache must carry, not how it is computed; tests/test_robust_design.py runs it).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from rodgains import design_cache
from rodgains import robust_design as R
from rodgains.design import design
from rodgains.params import load_params
from rodctl import paths

MATRIX_FILE = paths.REPO / "docs/tuned/robust-matrix.toml"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty cache folder, no in-process memo, and a refinement that records its calls."""
    folder = tmp_path / "designs"
    monkeypatch.setenv("RODGAINS_CACHE_DIR", str(folder))
    monkeypatch.setattr(R, "_MEMO", {})
    calls = []
    rng = np.random.default_rng(7)

    def fake_refine(p, dt, Ao, Bo, Co, Ko, Lo, disturbance, progress=None):
        calls.append(p.sha256())
        n = Ko.shape[1] - 1
        scale = 1.0 + 0.01 * rng.standard_normal(n)  # full float64 mantissas, as a real refinement gives
        return R.Refined(Ko[:, :n] * scale, Lo[:n] * 1.0, float(Lo[n, 0]) / 3.0, {"N=8 damping x1": 0.99712345678},
                         {"N=8 damping x1": 0.998}, 10, 7, 0.8,
                         {"holds": True, "runs": {"nominal": {"fell": False, "fell_at_s": None,
                                                              "final_deg": 0.123456789, "holds": True}}})

    monkeypatch.setattr(R, "_refine", fake_refine)
    return folder, calls


def _gains(d):
    return d.K.copy(), d.L.copy(), d.Lw


def test_a_second_process_gets_the_same_gains_without_refining(cache, monkeypatch):
    folder, calls = cache
    p = load_params(MATRIX_FILE)
    K1, L1, Lw1 = _gains(design(p))
    assert len(calls) == 1
    assert len(list(folder.glob("*.json"))) == 1
    monkeypatch.setattr(R, "_MEMO", {})  # as a new process would start
    d = design(p)
    K2, L2, Lw2 = _gains(d)
    assert len(calls) == 1  # served from disk
    assert np.array_equal(K1, K2) and np.array_equal(L1, L2) and Lw1 == Lw2  # bit-identical
    assert d.checks["robust_step"] == 0.8 and d.checks["robust_runs"] == [7, 10]
    assert d.checks["robust_release"]["runs"]["nominal"]["final_deg"] == 0.123456789
    assert not list(folder.glob("*.tmp"))  # no half-written file left behind


def test_a_changed_parameter_is_designed_anew(cache):
    folder, calls = cache
    design(load_params(MATRIX_FILE))
    design(load_params(MATRIX_FILE, ["design.robust_radius=0.9997"]))
    assert len(calls) == 2
    assert len(list(folder.glob("*.json"))) == 2


def test_a_change_of_the_design_code_is_designed_anew(cache, monkeypatch):
    folder, calls = cache
    p = load_params(MATRIX_FILE)
    design(p)
    monkeypatch.setattr(R, "_MEMO", {})
    monkeypatch.setattr(design_cache, "code_hash", lambda: "another version of rodgains")
    design(p)
    assert len(calls) == 2


@pytest.mark.parametrize("damage", ["not json", "another key", "wrong shape"])
def test_a_corrupt_entry_is_designed_anew_and_replaced(cache, monkeypatch, damage):
    folder, calls = cache
    p = load_params(MATRIX_FILE)
    K1, _, _ = _gains(design(p))
    (entry,) = folder.glob("*.json")
    entry.write_text({"not json": "{ half a record",
                      "another key": json.dumps(dict(json.loads(entry.read_text()), key="0" * 64)),
                      "wrong shape": json.dumps({"key": entry.stem, "K": [[1.0, 2.0]], "L": [[1.0]], "Lw": 0.0,
                                                 "radii": {}, "radii_lqg": {}, "runs": 1, "agree": 1, "step": 1.0,
                                                 "release": None})}[damage])
    monkeypatch.setattr(R, "_MEMO", {})
    K2, _, _ = _gains(design(p))
    assert len(calls) == 2
    assert np.all(np.isfinite(K2)) and K2.shape == K1.shape
    assert json.loads(entry.read_text())["key"] == entry.stem  # rewritten whole


def test_an_unwritable_cache_still_designs(cache, tmp_path, monkeypatch):
    _, calls = cache
    blocker = tmp_path / "a file, not a folder"
    blocker.write_text("")
    monkeypatch.setenv("RODGAINS_CACHE_DIR", str(blocker / "designs"))
    d = design(load_params(MATRIX_FILE))
    assert len(calls) == 1 and d.checks["closed_loop_spectral_radius"] < 1.0


def test_the_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("RODGAINS_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert design_cache.directory() == tmp_path / "xdg" / "rodgains"
    monkeypatch.setenv("RODGAINS_CACHE_DIR", str(tmp_path / "mine"))
    assert design_cache.directory() == tmp_path / "mine"


def test_a_write_that_fails_midway_leaves_the_old_file_and_no_temporary(tmp_path):
    """rodgains.atomic_file (the cache's, the logs' and the robustness outputs' writer): a reader sees
    the old file or the new one, never half of one."""
    from rodgains.atomic_file import atomic_write, replacing

    target = atomic_write(tmp_path / "out" / "run.json", '{"old": 1}\n')
    assert target.read_text() == '{"old": 1}\n'
    with pytest.raises(RuntimeError):
        with replacing(target) as tmp:
            tmp.write_text('{"new": ')
            raise RuntimeError("the writer died")
    assert target.read_text() == '{"old": 1}\n'
    assert sorted(p.name for p in target.parent.iterdir()) == ["run.json"]
    atomic_write(target, b'{"new": 2}\n')
    assert target.read_text() == '{"new": 2}\n'
    assert sorted(p.name for p in target.parent.iterdir()) == ["run.json"]


def test_regenerating_writes_only_the_files_that_changed(tmp_path):
    """rodgains.atomic_file.write_changed (the gains header before a build, the reference pages): a file
    already holding its text is left alone (its time unchanged, so a firmware build does not redo it)."""
    import os

    from rodgains.atomic_file import stale, write_changed

    same, old, missing = tmp_path / "same.h", tmp_path / "old.h", tmp_path / "new" / "missing.toml"
    same.write_text("kept\n")
    old.write_text("before\n")
    os.utime(same, (1_000_000_000, 1_000_000_000))
    files = {same: "kept\n", old: "after\n", missing: "made\n"}
    assert stale(files) == [old, missing]
    assert write_changed(files) == [old, missing]
    assert [f.read_text() for f in files] == ["kept\n", "after\n", "made\n"]
    assert same.stat().st_mtime == 1_000_000_000
    assert stale(files) == [] and write_changed(files) == []
