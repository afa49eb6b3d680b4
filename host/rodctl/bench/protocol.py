"""How fast the host decodes telemetry: N=5 frames through protocol.Decoder, fed in serial-sized chunks.

    python3 -m rodctl.bench.protocol [SECONDS]

The device sends one telemetry frame per control period (1 kHz at decimation 1); the host must keep
up with room to spare while it also logs and plots, so the goal is >= 100,000 frames/s.
"""

from __future__ import annotations

import math
import random
import statistics
import sys
import time

from rodctl.link import protocol as P

CHUNK = 4096  # bytes per read, like a USB serial read


def telemetry_stream(frames: int = 2000, n: int = 5, seed: int = 1) -> bytes:
    """A realistic stream: balance near upright, small counters (so the packets have many zero bytes)."""
    rng = random.Random(seed)
    out = []
    for k in range(frames):
        t = P.Telemetry(
            mode=P.Mode.BALANCE, reason=P.Reason.NONE,
            flags=int(P.TelemetryFlag.DRIVER_ENABLED | P.TelemetryFlag.HEARTBEAT_OK), n=n,
            encoder_count=490 + rng.randint(-40, 40), base_rate=rng.uniform(-3, 3), torque=rng.uniform(-0.2, 0.2),
            duty=rng.uniform(-1, 1), step_us=rng.randint(40, 90), overruns=0, frames_dropped=k // 700, rx_errors=0,
            theta_hat=tuple(math.pi + rng.uniform(-0.3, 0.3) for _ in range(n)),
            rate_hat=tuple(rng.uniform(-4, 4) for _ in range(n)))
        out.append(P.encode_telemetry(t, seq=k, time_us=1000 * k))
    return b"".join(out)


def _one_run(chunks: list[bytes], frames_per_pass: int, seconds: float) -> float:
    dec = P.Decoder()
    done = 0
    t0 = time.perf_counter()
    while True:
        dec.reset_seq()
        for c in chunks:
            dec.feed(c)
        done += frames_per_pass
        dt = time.perf_counter() - t0
        if dt >= seconds:
            break
    if dec.frames != done or dec.errors:
        raise RuntimeError(f"benchmark stream did not decode cleanly: {dec.counters()}")
    return done / dt


def measure_decode_rate(seconds: float = 1.0, runs: int = 5, n: int = 5) -> float:
    """Median over `runs` runs of telemetry frames decoded per second (each run about seconds / runs)."""
    frames = 2000
    blob = telemetry_stream(frames, n)
    chunks = [blob[i:i + CHUNK] for i in range(0, len(blob), CHUNK)]
    _one_run(chunks, frames, 0.0)  # warm up: struct caches, code paths
    return statistics.median(_one_run(chunks, frames, seconds / runs) for _ in range(runs))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    seconds = float(argv[0]) if argv else 2.0
    rate = measure_decode_rate(seconds)
    print(f"decode N=5 telemetry: {rate:,.0f} frames/s (median, goal >= 100,000)")
    return 0 if rate >= 100_000 else 1


if __name__ == "__main__":
    sys.exit(main())
