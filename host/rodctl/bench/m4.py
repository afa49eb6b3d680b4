"""Instruction counts of one control step on a Cortex-M4F (QEMU + TCG plugin), N = 5 and N = 20.

One step = rod_device_step in BALANCE (observer + LQR, the expensive mode) plus encoding the
telemetry frame that step produced (rod_device_tx), at telemetry decimation 1: the worst case
the control interrupt and the main loop share per period. Averaged over many steps of a
deterministic encoder trace near upright. Uses /work/shared/tools/m4-icount.sh (`cc`, `run ELF
START STOP`); the numbers are instructions, not cycles.

    python -m rodctl.bench.m4            # prints the dict of measure()
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

from rodgains.errors import UserError

from rodctl import paths

from rodctl.build import target_build

# The workplace's QEMU instruction counter: $ROD_M4_ICOUNT, else ../shared/tools beside the checkout.
ICOUNT_CANDIDATES = [Path(p) for p in (os.environ.get("ROD_M4_ICOUNT", ""),) if p] + [
    paths.REPO.parent / "shared" / "tools" / "m4-icount.sh", Path("/work/shared/tools/m4-icount.sh")]
ICOUNT = next((p for p in ICOUNT_CANDIDATES if p.is_file()), ICOUNT_CANDIDATES[0])
STEPS = 2000
M4_GOAL_KEYS = ("m4_step_instructions_n5", "m4_step_instructions_n20", "m4_step_instructions_imu")  # bench.suite.GOALS

BENCH_C = r"""
#include <stdio.h>
#include "rod_device.h"

__attribute__((noinline)) void bench_start(void) { __asm__ volatile(""); }
__attribute__((noinline)) void bench_stop(void) { __asm__ volatile(""); }

static rod_device_t dev;
static uint8_t frame[ROD_DEVICE_FRAME_MAX];

static void drain(void)
{
    while (rod_device_tx(&dev, frame, sizeof frame) > 0) {
    }
}

int main(void)
{
    /* the tip IMU upright (a firmware without it ignores the sample), its readings moving as a live part's do */
    rod_inputs_t in = {490, 0u, 0u, false, {0.0f, 9.81f, 0.0f, true}};
    rod_outputs_t out;
    rod_device_init(&dev);
    rod_msg_command_t arm = {.type = ROD_MSG_ARM, .seq = 1u, .status = ROD_ACK_OK, .arm_mode = ROD_ARM_BALANCE};
    rod_device_post_command(&dev, &arm);
    rod_device_step(&dev, &in, &out); /* arm, catch: BALANCE from here on */
    drain();
    size_t bytes = 0;
    for (int k = 0; k < BENCH_STEPS; k++) {
        /* a slow wobble of a few counts around upright keeps the estimator busy */
        int phase = (k / 40) % 8;
        in.encoder_count = 490 + (phase < 4 ? phase : 8 - phase) - 2;
        in.now_us += ROD_LOOP_PERIOD_US;
        in.imu.gyro = 0.001f * (float)(k % 5) - 0.002f;
        in.imu.accel_y = 0.01f * (float)(k % 7) - 0.03f;
        rod_device_heartbeat(&dev);
        bench_start();
        rod_device_step(&dev, &in, &out);
        bytes += rod_device_tx(&dev, frame, sizeof frame);
        bench_stop();
        drain(); /* an occasional HELLO, outside the window */
    }
    printf("mode %d reason %d enable %d bytes %u device %u\n", dev.control.mode, dev.control.reason,
           out.enable ? 1 : 0, (unsigned)bytes, (unsigned)sizeof(rod_device_t));
    return 0;
}
"""


def _icount_tool() -> Path:
    if not ICOUNT.is_file():
        raise UserError(f"m4-icount.sh not found (looked in {', '.join(map(str, ICOUNT_CANDIDATES))}); "
                        "set ROD_M4_ICOUNT to the script")
    return ICOUNT


def header_for_edges(n: int | None, out_dir: Path, *overrides: str, name: str | None = None) -> Path:
    """What `rodctl gains --set rod.edges=n [--set ...] --header out_dir/<name>/rod_gains.h` writes (never the
    committed one); n None keeps the default order."""
    from rodgains.atomic_file import write_changed

    from rodctl.build.header import generated_files

    header = out_dir / (name or f"n{n}") / "rod_gains.h"
    sets = ([f"rod.edges={n}"] if n is not None else []) + list(overrides)
    _, files = generated_files(None, sets, str(header))
    write_changed(files)
    return header


def step_instructions(header: Path, work: Path) -> tuple[float, str]:
    """Average instructions per (BALANCE step + telemetry encode) against `header`."""
    tool = _icount_tool()
    work.mkdir(parents=True, exist_ok=True)
    src = work / "bench_step.c"
    src.write_text(BENCH_C)
    elf = work / "bench_step.elf"
    inc = target_build.header_dir(header, work)
    sources = [str(p) for p in target_build.core_sources()]
    env = dict(os.environ)
    cc = subprocess.run(["bash", str(tool), "cc", str(elf), str(src), *sources, f"-I{inc}", f"-I{paths.CORE_SRC}",
                         f"-DBENCH_STEPS={STEPS}", "-std=c11", "-Wall", "-Wextra", "-Wdouble-promotion", "-Werror"],
                        capture_output=True, text=True, env=env)
    if cc.returncode != 0:
        raise UserError(f"building the M4 benchmark failed: {(cc.stderr or cc.stdout).strip().splitlines()[:1]}")
    run = subprocess.run(["bash", str(tool), "run", str(elf), "bench_start", "bench_stop"],
                         capture_output=True, text=True, env=env)
    text = run.stdout + run.stderr
    m = re.search(r"icount window (\d+) \(entered (\d+) times\)", text)
    if run.returncode != 0 or not m:
        raise UserError(f"running the M4 benchmark failed: {text.strip()[-300:]}")
    total, entries = int(m.group(1)), int(m.group(2))
    guest = re.search(r"mode (\d+) reason (\d+) enable (\d+)", text)
    if not guest or guest.group(1) != "1":
        raise UserError(f"benchmark did not stay in BALANCE: {text.strip()[-200:]}")
    # The window includes the START marker's own `bx lr` once per entry.
    return (total - entries) / entries, text


def measure() -> dict:
    work = paths.BUILD / "bench_m4"
    n5 = header_for_edges(5, work / "headers")  # the committed header has the default N (rod.edges)
    n20 = header_for_edges(20, work / "headers")
    i5, _ = step_instructions(n5, work / "n5")
    i20, _ = step_instructions(n20, work / "n20")
    idef, _ = step_instructions(paths.COMMITTED_HEADER, work / "default")
    imu = header_for_edges(None, work / "headers", "sensors.tip_imu=true", name="imu")
    iimu, _ = step_instructions(imu, work / "imu")
    size = target_build.build(paths.COMMITTED_HEADER)
    return {
        "m4_step_instructions_n5": round(i5, 1),
        "m4_step_instructions_n20": round(i20, 1),
        "m4_step_instructions_default": round(idef, 1),
        "m4_step_instructions_imu": round(iimu, 1),
        "m4_core_flash_bytes": size.flash_bytes,
        "m4_core_ram_bytes": size.ram_bytes,
    }


def main() -> int:
    try:
        result = measure()
    except UserError as e:
        print(f"bench: {e}", file=sys.stderr)
        return 1
    from rodctl.bench.suite import GOALS

    print(json.dumps(result, indent=1))
    for key in M4_GOAL_KEYS:
        goal = GOALS[key][0]
        print(f"{key}: {result[key]} (goal <= {goal:g}) {'ok' if result[key] <= goal else 'OVER'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
