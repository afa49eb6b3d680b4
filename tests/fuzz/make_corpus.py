"""Write the seed corpus of tests/fuzz/rx_device_fuzz.c into tests/fuzz/corpus/ (committed).

    python tests/fuzz/make_corpus.py [OUT_DIR]

Each seed is a host session as rx_device_fuzz.c reads it: chunks of [size - 1][bytes], here one
chunk per wire frame. Seeds: every command alone, arm-then-set sequences at and just outside
each setting's range, the short frames the host must survive, and a stream broken mid-frame.
"""

from __future__ import annotations

import math
import struct
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "host"))

from rodctl.link import protocol as P  # noqa: E402


def chunked(frames: list[bytes]) -> bytes:
    out = b""
    for f in frames:
        while f:
            part, f = f[:64], f[64:]
            out += bytes([len(part) - 1]) + part
    return out


def seeds() -> dict[str, bytes]:
    """{seed name: file content}."""
    seq = iter(range(1, 10_000))
    enc = lambda m: P.encode(m, next(seq))  # noqa: E731
    arm_swing, arm_bal = enc(P.Arm(P.ArmMode.SWING_UP)), enc(P.Arm(P.ArmMode.BALANCE))
    seeds = {
        "hello_request": [enc(P.HelloRequest())],
        "heartbeat": [enc(P.Heartbeat())],
        "arm_swing_up_then_disarm": [arm_swing, enc(P.Heartbeat()), enc(P.Disarm())],
        "arm_balance_clear_fault": [arm_bal, enc(P.ClearFault())],
        "short_telemetry": [P.encode_packet(P.MsgType.TELEMETRY, 7, 0, b""), enc(P.HelloRequest())],
        "short_set": [P.encode_packet(P.MsgType.SET, 8, 0, b"\x03"), enc(P.HelloRequest())],
        "broken_mid_frame": [enc(P.Set(P.Param.CATCH_ANGLE, 0.5))[:5], enc(P.HelloRequest())],
    }
    for c in P.SPEC.codes["param"].values:
        p = P.Param(c.value)
        hi = c.max if c.max is not None else 0.2
        for label, v in (("min", c.min), ("below", c.min * 0.5), ("max", hi), ("above", hi * 1.5),
                         ("denormal", 1e-40), ("huge", 1e30), ("nan", math.nan)):
            seeds[f"set_{c.name.lower()}_{label}"] = [arm_swing, enc(P.Set(p, v)), enc(P.Heartbeat())]
    raw_nan = struct.pack("<Bf", P.Param.CATCH_ANGLE, math.inf)
    seeds["set_catch_inf"] = [P.encode_packet(P.MsgType.SET, 9, 0, raw_nan)]
    return {f"seed_{name}": chunked(frames) for name, frames in sorted(seeds.items())}


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "corpus"
    out.mkdir(exist_ok=True)
    for old in out.glob("seed_*"):
        old.unlink()
    files = seeds()
    for name, data in files.items():
        (out / name).write_bytes(data)
    print(f"wrote {len(files)} seeds to {out}")


if __name__ == "__main__":
    main()
