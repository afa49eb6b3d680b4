"""Fitting the experiments' logs (`rodctl identify`, after the board's run or on recorded LOG files):
the records of the runs that played to their end, the fit, the friction compensation for the
identified rig, the verdict, and the parameter file and figure they write.

    from rodctl.ident.fit_logs import fit_logs
    ok = fit_logs(paths, nominal=lambda meta: (load_params(), "defaults"), out=Path("my_rod.toml"),
                  plot=Path("my_rod.png"), say=say, show=print)   # True: READY, every value in range
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from rodgains.atomic_file import atomic_write
from rodgains.errors import InputError


def _ended_early(meta: dict) -> str | None:
    """How an experiment log of `rodctl identify` ended when it did not play to its end ("stopped: swung
    ..." past the soft limit, "interrupted: Ctrl-C" or the stop signal's name, "interrupted: a lost link or an
    error" where the log says "error", "fault", "timeout"); None for a complete run, or a log without that
    record (another tool's, or one a kill cut off)."""
    end = meta.get("end")
    if end in (None, "", "done"):
        return None
    return "interrupted: a lost link or an error" if end == "error" else str(end)


def incomplete_run(path: Path) -> str | None:
    """_ended_early for a log on disk."""
    from rodctl.logs import read_log

    try:
        return _ended_early(read_log(path, columns=["mode_code"]).trailer)
    except Exception:  # noqa: BLE001 - an unreadable log is reported by the fit that reads it
        return None


def buckling_line(identified) -> str:
    """How far the identified rod is from buckling, and which matrix cases take it past."""
    from rodgains.buckling import clamped_ratio, margins_text

    from rodctl.sim.matrix import buckled_cases

    ratio = clamped_ratio(identified)
    text = (f"buckling: the rod above the hub is {ratio:.3f} x its clamped buckling length (Greenhill's"
            + (", with the tip IMU's mass)" if identified["sensors"]["tip_imu"] else ")")
            + (f"; it reaches 1 at {margins_text(identified)}" if 0.0 < ratio < 1.0 else ""))
    past = buckled_cases(identified)
    if past:
        text += ("\n  past it in the robustness matrix: " + ", ".join(f"{n} {v:.3f} x" for n, v in past.items())
                 + "; measured, no design held a matrix run straight past 1.002 x (docs/identification.md)")
    return text


def _choose_compensation(identified, cases: str, jobs: int | None, say: Callable[[str], None],
                         show: Callable[[str], None]):
    """The friction compensation for the identified rig, judged by the matrix (ident/compensation.py);
    None: keep the nominal file's."""
    from rodctl.ident import compensation as C

    if cases == "none":
        return None
    if identified["motor"]["coulomb_friction"] < C.MIN_COULOMB_NM:
        choice = C.without_friction(identified, cases)
        show(f"friction compensation: 0 mN m ({choice.note})")
        return choice
    say(f"friction compensation: {', '.join(f'{r:g}' for r in C.RATIOS)} x the identified Coulomb friction and "
        f"the nominal file's {1e3 * identified['lqr']['friction_compensation']:.2f} mN m, each judged by the "
        f"robustness matrix ({cases}) on the identified rig with an ideal gearbox (the play's "
        "lean would swamp the difference; the closing verdict keeps the play, so its counts differ)")
    choice = C.choose(identified, cases=cases, jobs=jobs, say=lambda line: say(f"friction compensation: {line}"))
    for c in choice.candidates:
        say(f"  {c.line()}")
    show(f"friction compensation: {1e3 * choice.best.torque_nm:.2f} mN m ({choice.best.ratio:.3g} x)"
         f"{choice.best.with_weight(', ')}")
    return choice


def _verdict(written, cases: str, jobs: int | None, say: Callable[[str], None]):
    """The matrix on the identified rig's faithful plant with the design about to be written."""
    from rodctl.ident.verdict import judge

    cases = "nominal" if cases == "none" else cases
    say(f"verdict: the written design on the identified rig, gearbox included (matrix case set {cases})")
    return judge(written, cases, jobs=jobs)


def fit_logs(logs: list[Path], params=None, source: str = "", *, nominal, out: Path, plot: Path, starts: int = 3,
             exact: bool = False, cases: str = "matrix", jobs: int | None = None, say: Callable[[str], None],
             show: Callable[[str], None]) -> bool:
    """Fit the logs that played to their end, choose the friction compensation by the `cases` set of the
    robustness matrix ("none": keep the nominal file's), judge the written design, and write the
    parameter file `out` and the figure `plot`. params, source: the fit's nominal rig; None: nominal(meta)
    with the first fitted log's metadata, which returns (Params, where from). starts: optimizer starts;
    exact: every start on the file's [plant]; jobs: matrix worker processes (None: every core).
    say(text): progress (stderr); show(text): the results (stdout). True: READY and every value within
    its physical range."""
    from rodctl.ident import experiments as E
    from rodctl.ident import fit as F
    from rodctl.ident import report as R
    from rodctl.logs.reader import cut_short

    records, digests, meta0, skipped = [], [], None, 0
    for path in logs:
        digest = E.file_sha256(path)
        same = next((name for name, d in digests if d == digest), None)
        if same is not None:  # one experiment fitted twice would weigh twice
            say(f"fit: skipping {path}: the same log as {same}")
            continue
        log, recs = E.records_from_log(path, digest=digest)
        meta = log.meta
        short = cut_short(log)
        if short is not None:
            say(f"fit: warning: {short}; fitting the readable part")
        if "end" in meta and "experiment" not in meta:  # closed by `rodctl log` or `arm`, not by identify's run
            say(f"fit: skipping {path}: not an experiment of rodctl identify (a `rodctl log` recording?)")
            skipped += 1
            continue
        why = _ended_early(meta)
        if why is not None:
            # the live run fits only the runs that played to their end (a stopped one is played again
            # smaller): fitting its logs afterwards, by the glob a Ctrl-C names, must fit the same records
            say(f"fit: skipping {path}: the experiment did not play to its end ({why})")
            skipped += 1
            continue
        meta0 = meta0 or meta
        records += recs
        digests.append((Path(path).name, digest))
    if skipped and not digests:
        raise InputError(f"no experiment log played to its end ({skipped} skipped): nothing to fit")
    if params is None:
        params, source = nominal(meta0)
    say(f"fit: {len(records)} records, {sum(r.seconds for r in records):.1f} s of excitation; nominal: {source}")
    model = F.fit_model(params, exact=exact)
    own = "the parameter file's [plant]"
    say(f"fit plant: {own if not model else ', '.join(model) + ', then a polish on ' + own}")
    res = F.fit(records, params, starts=starts, progress=say, model=model)
    show(f"identified in {res.seconds:.1f} s ({res.evaluations} simulations); "
         f"theta_1 residual {res.rms_counts:.2f} counts RMS; validation (held-out {100 * F.VALIDATION_FRACTION:g} %): "
         f"{F.validation_text(res.validation_fit_pct)}")
    miss = F.model_miss_text(res.rms_counts)
    if miss:
        say(f"rodctl: warning: {miss}")
    show("\n".join(F.report_lines(res)))
    show("identifiability:")
    show("\n".join("  " + s for s in F.identifiability_text(res)))
    identified = R.identified_params(params, res)
    show(buckling_line(identified))
    choice = _choose_compensation(identified, cases, jobs, say, show)
    verdict = _verdict(R.written_params(params, res, choice), cases, jobs, say)
    lines = verdict.lines(str(out))
    atomic_write(out, R.parameter_file(params, res, digests, compensation=choice, verdict=lines))
    R.figure(res, plot)
    show(f"wrote {out} and {plot}")
    for name, why in res.out_of_range.items():
        say(f"rodctl: {name}: {why}; kept nominal in {out}")
    show("\n".join(lines))  # last, where no one can miss it
    return verdict.ready and not res.out_of_range
