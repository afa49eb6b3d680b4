"""Write tests/vectors/rodlink_vectors.json: exact rodlink v2 wire bytes both codecs must produce.

    python3 tests/make_vectors.py            # rewrite the JSON (then review the diff and commit it)
    python3 tests/make_vectors.py --check    # exit 1 if the committed JSON differs

The wire bytes here come from an independent reference encoder written straight from the v2 wire
specification (explicit struct formats, the textbook COBS loop, a bit-by-bit CRC), not from
host/rodctl/link/protocol.py or the TOML. The script also checks that rodctl.link.protocol agrees before writing,
so a mismatch between the TOML layout and the specification stops here. tests/test_protocol.py
compares both codecs against the committed JSON, never against this script.

Field values are chosen exactly representable as float32, so they survive JSON unchanged.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
from pathlib import Path

OUT = Path(__file__).resolve().parent / "vectors" / "rodlink_vectors.json"

# ---- reference implementation of the v2 wire specification ----------------------------------


def ref_crc16(data: bytes) -> int:
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def ref_cobs(data: bytes) -> bytes:
    """Cheshire & Baker COBS; a 254-byte non-zero run ending the data takes no extra code byte."""
    out = bytearray([0])
    code_i, code = 0, 1
    for i, b in enumerate(data):
        if b == 0:
            out[code_i] = code
            code_i, code = len(out), 1
            out.append(0)
        else:
            out.append(b)
            code += 1
            if code == 0xFF:
                out[code_i] = code
                if i == len(data) - 1:
                    return bytes(out)
                code_i, code = len(out), 1
                out.append(0)
    out[code_i] = code
    return bytes(out)


VERSION = 2
TYPES = {"TELEMETRY": 0x01, "HELLO": 0x02, "ACK": 0x03, "IMU": 0x04, "HEARTBEAT": 0x10, "ARM": 0x11, "DISARM": 0x12,
         "CLEAR_FAULT": 0x13, "SET": 0x14, "HELLO_REQUEST": 0x15, "IDENTIFY": 0x16,
         "SAVE_RIG": 0x17}


def ref_payload(name: str, f: dict) -> bytes:
    if name == "TELEMETRY":
        n = f["n"]
        return (struct.pack("<BBBBifffHHIII", f["mode"], f["reason"], f["flags"], n, f["encoder_count"],
                            f["base_rate"], f["torque"], f["duty"], f["step_us"], 0, f["overruns"],
                            f["frames_dropped"], f["rx_errors"])
                + struct.pack(f"<{n}f", *f["theta_hat"]) + struct.pack(f"<{n}f", *f["rate_hat"]))
    if name == "HELLO":
        return struct.pack("<BBBBBBBBIHHfffff32sIHH", f["fw_major"], f["fw_minor"], f["fw_patch"], f["gains_schema"],
                           f["n"], f["mode"], f["reason"], f["rig"], f["period_us"], f["decimation"], 0,
                           f["swing_amplitude"], f["swing_angle"], f["catch_angle"], f["heartbeat_timeout"],
                           f["torque_max"], bytes.fromhex(f["header_sha256"]), f["counts_num"], f["counts_den"], 0)
    if name == "ACK":
        return struct.pack("<BBIBB", f["command"], f["result"], f["command_seq"], f["mode"], 0)
    if name == "IMU":
        return struct.pack("<fffffBBH", f["gyro"], f["accel_x"], f["accel_y"], f["gyro_bias"], f["encoder_offset"],
                           f["status"], 0, f["bad_run"])
    if name == "ARM":
        return struct.pack("<B", f["mode"])
    if name == "SET":
        return struct.pack("<Bf", f["param"], f["value"])
    if name == "IDENTIFY":
        return struct.pack("<BBHffff", f["excitation"], 0, f["seed"], f["amplitude"], f["duration"], f["shape1"],
                           f["shape2"])
    assert not f, name
    return b""


def ref_frame(name: str, seq: int, time_us: int, fields: dict) -> bytes:
    body = struct.pack("<BBII", VERSION, TYPES[name], seq, time_us) + ref_payload(name, fields)
    return ref_cobs(body + struct.pack("<H", ref_crc16(body))) + b"\0"


# ---- cases ------------------------------------------------------------------------------------


def cobs_codes(enc: bytes) -> list[int]:
    codes, i = [], 0
    while i < len(enc):
        codes.append(enc[i])
        i += enc[i]
    return codes


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def nz(x: float) -> float:
    """The float32 nearest x (stepping up in ulps) whose four bytes are all non-zero."""
    bits = struct.unpack("<I", struct.pack("<f", x))[0]
    while 0 in struct.pack("<I", bits):
        bits += 1
    return struct.unpack("<f", struct.pack("<I", bits))[0]


def telemetry(n: int, *, mode=1, reason=0, flags=5, enc=490, base_rate=0.0125, torque=-0.0125, duty=-0.0625,
              step_us=61, overruns=0, dropped=0, rx_errors=0, theta=None, rate=None) -> dict:
    theta = theta if theta is not None else [3.14159 - 0.02 * k for k in range(n)]
    rate = rate if rate is not None else [0.37 * (k + 1) * (-1) ** k for k in range(n)]
    return {"mode": mode, "reason": reason, "flags": flags, "n": n, "encoder_count": enc, "base_rate": f32(base_rate),
            "torque": f32(torque), "duty": f32(duty), "step_us": step_us, "overruns": overruns,
            "frames_dropped": dropped, "rx_errors": rx_errors, "theta_hat": [f32(x) for x in theta],
            "rate_hat": [f32(x) for x in rate]}


def cases() -> list[dict]:
    C = []

    def add(case: str, name: str, seq: int, time_us: int, fields: dict, note: str) -> None:
        C.append({"case": case, "message": name, "type": TYPES[name], "seq": seq, "time_us": time_us,
                  "fields": fields, "note": note, "wire": ref_frame(name, seq, time_us, fields).hex()})

    add("telemetry_n5", "TELEMETRY", 1000, 123456789, telemetry(5), "typical balance frame, small counters")
    add("telemetry_n1_negative_max", "TELEMETRY", 0xFFFFFFFF, 0xFFFFFFFF,
        telemetry(1, mode=3, reason=7, flags=0x07, enc=-2147483648, base_rate=-39.5, torque=-0.2, duty=-1.0,
                  step_us=65535, overruns=0xFFFFFFFF, dropped=0xFFFFFFFE, rx_errors=0x80000000,
                  theta=[-3.4028234663852886e38], rate=[3.4028234663852886e38]),
        "negative and extreme values: INT32_MIN count, u32/u16 max, +-FLT_MAX")
    add("telemetry_n1_negative", "TELEMETRY", 1, 2, telemetry(1, mode=2, enc=-1, base_rate=-12.25, torque=-0.0078125,
                                                             duty=-0.5, theta=[-0.75], rate=[-100.5]),
        "negative count -1 (ff ff ff ff) and negative floats")
    add("telemetry_n0", "TELEMETRY", 5, 6, telemetry(0, mode=0, flags=0, enc=0, base_rate=0.0, torque=0.0, duty=0.0,
                                                    step_us=0), "no estimate, all zero: every byte a COBS code")
    add("telemetry_n25_short_max", "TELEMETRY", 77, 88, telemetry(25), "largest packet under 254 bytes (248)")
    ones = dict(reason=1, enc=0x01010101, step_us=0x0101, overruns=0x01010101, dropped=0x01010101,
                rx_errors=0x01010101, base_rate=nz(1.5), torque=nz(-0.125), duty=nz(0.75))
    add("telemetry_n30_ff_block_at_end", "TELEMETRY", 0x01010101, 0x01010101,
        telemetry(30, **ones, theta=[nz(3.0 + 0.01 * k) for k in range(30)], rate=[nz(1.0 + 0.03 * k) for k in range(30)]),
        "288-byte packet ending in a 254-byte zero-free run: a final 0xFF COBS block with no code after it")
    add("telemetry_n31_ff_block", "TELEMETRY", 0x01010101, 0x01010101,
        telemetry(31, **ones, theta=[nz(3.0 + 0.01 * k) for k in range(31)], rate=[nz(1.0 + 0.03 * k) for k in range(31)]),
        "296-byte packet with a 262-byte zero-free run: a 0xFF COBS block then a short one")
    add("telemetry_n64", "TELEMETRY", 424242, 4242424242, telemetry(64), "largest frame (n = max_n)")
    for c in C:  # the long cases must really exercise 0xFF blocks
        if "ff_block" in c["case"]:
            assert 0xFF in cobs_codes(bytes.fromhex(c["wire"])[:-1]), c["case"]
    add("hello", "HELLO", 0, 1500, {
        "fw_major": 1, "fw_minor": 2, "fw_patch": 3, "gains_schema": 1, "n": 5, "mode": 0, "reason": 0, "rig": 0x05,
        "period_us": 1000, "decimation": 10, "swing_amplitude": f32(0.01), "swing_angle": f32(0.5235988),
        "catch_angle": f32(0.5235988), "heartbeat_timeout": f32(0.5), "torque_max": f32(0.2),
        "header_sha256": "bf696209351be89d53b64b5f4cabfdd2f0bb0dd5d367d8ae87a4c93c984f5843",
        "counts_num": 4896, "counts_den": 5},
        "power-on hello; rig 0x05: encoder reversed, stored; 979.2 counts per turn")
    add("ack_ok", "ACK", 1001, 123457000, {"command": 0x11, "result": 0, "command_seq": 42, "mode": 4},
        "arm balance accepted, now CATCH")
    add("ack_bad_state", "ACK", 1002, 123458000, {"command": 0x11, "result": 2, "command_seq": 0xFFFFFFFF, "mode": 3},
        "arm refused in FAULT")
    add("ack_unknown", "ACK", 7, 8, {"command": 0x7E, "result": 3, "command_seq": 9, "mode": 0}, "unknown command")
    add("imu_balancing", "IMU", 1003, 123459000, {"gyro": f32(-0.0123), "accel_x": f32(9.7012), "accel_y": f32(0.1712),
        "gyro_bias": f32(0.0087), "encoder_offset": f32(-0.0052), "status": 0x07, "bad_run": 0},
        "a good sample while balancing; bias measured at rest")
    add("imu_lost", "IMU", 1004, 123460000, {"gyro": f32(0.0), "accel_x": f32(0.0), "accel_y": f32(0.0),
        "gyro_bias": f32(0.0), "encoder_offset": f32(0.0), "status": 0x00, "bad_run": 15},
        "no sample for 15 periods: the FAULT IMU threshold")
    add("heartbeat", "HEARTBEAT", 43, 1000000, {}, "")
    add("arm_balance", "ARM", 44, 1000100, {"mode": 1}, "catch near upright")
    add("arm_swing_up", "ARM", 45, 1000200, {"mode": 2}, "swing up then balance")
    add("disarm", "DISARM", 46, 1000300, {}, "")
    add("clear_fault", "CLEAR_FAULT", 47, 1000400, {}, "")
    add("hello_request", "HELLO_REQUEST", 0, 0, {}, "all-zero header fields")
    add("save_rig", "SAVE_RIG", 61, 1000700, {}, "store the signs on the board")
    for param, value, label in [(1, 0.015, "swing_amplitude"), (2, 0.6, "swing_angle"), (3, 0.35, "catch_angle"),
                                (4, 10.0, "telemetry_decimation"), (5, 0.25, "heartbeat_timeout"),
                                (6, -1.0, "encoder_sign"), (7, -1.0, "motor_sign"), (8, 1958.4, "counts_per_rev")]:
        add(f"set_{label}", "SET", 48 + param, 1000500 + param, {"param": param, "value": f32(value)}, f"SET {label}")
    add("set_negative", "SET", 60, 0xFFFFFFFF, {"param": 1, "value": f32(-1e-3)}, "negative value (device says BAD_VALUE)")
    for exc, label, amp, dur, s1, s2, seed in [(1, "chirp", 0.02, 8.0, 0.5, 6.0, 0),
                                               (2, "prbs", 0.015, 6.0, 0.025, 0.0, 0xACE1),
                                               (3, "steps", 0.01, 4.0, 0.25, 0.0, 0),
                                               (4, "release", 0.03, 5.0, 0.1, 0.0, 0)]:
        add(f"identify_{label}", "IDENTIFY", 70 + exc, 2000000 + exc,
            {"excitation": exc, "seed": seed, "amplitude": f32(amp), "duration": f32(dur), "shape1": f32(s1),
             "shape2": f32(s2)}, f"IDENTIFY {label}")
    return C


def cobs_cases() -> list[dict]:
    out = []
    for label, data in [
        ("empty", b""),
        ("one_zero", b"\x00"),
        ("two_zeros", b"\x00\x00"),
        ("mixed", bytes.fromhex("11220033")),
        ("trailing_zero", bytes.fromhex("11223344") + b"\x00"),
        ("run_254", bytes(range(1, 255))),
        ("zero_then_run_254", b"\x00" + bytes(range(1, 255))),
        ("run_255", bytes(range(1, 256))),
        ("run_300", bytes((i % 255) + 1 for i in range(300))),
        ("run_254_then_zero_x", bytes(range(1, 255)) + b"\x00\x07"),
    ]:
        out.append({"case": label, "data": data.hex(), "encoded": ref_cobs(data).hex()})
    return out


def document() -> dict:
    fixed = {"one_zero": "0101", "mixed": "0311220233"}
    cobs = cobs_cases()
    for c in cobs:  # the textbook examples, stated independently of ref_cobs
        if c["case"] in fixed:
            assert c["encoded"] == fixed[c["case"]], c
    assert ref_crc16(b"123456789") == 0x29B1
    return {
        "description": "rodlink v2 test vectors: wire = COBS(header | payload | crc16-LE) + 0x00. "
                       "Generated by tests/make_vectors.py from an independent reference encoder; "
                       "both codecs must produce exactly these bytes and decode them to these values.",
        "protocol_version": VERSION,
        "crc16": [{"data_ascii": "123456789", "crc": 0x29B1}, {"data_ascii": "", "crc": 0xFFFF},
                  {"data_hex": "00", "crc": ref_crc16(b"\0")}],
        "cobs": cobs,
        "messages": cases(),
    }


def check_against_host_codec(doc: dict) -> None:
    """The TOML-driven codec must agree with the reference; refuse to write vectors otherwise."""
    from rodctl.link import protocol as P

    for c in doc["messages"]:
        cls = P.MESSAGE_CLASSES[c["type"]]
        fields = dict(c["fields"])
        if "header_sha256" in fields:
            fields["header_sha256"] = bytes.fromhex(fields["header_sha256"])
        wire = P.encode(cls(**fields), c["seq"], c["time_us"]).hex()
        if wire != c["wire"]:
            raise SystemExit(f"make_vectors: rodctl.link.protocol disagrees with the reference on {c['case']}:\n"
                             f"  reference {c['wire']}\n  protocol  {wire}")
    for c in doc["cobs"]:
        if P.cobs_encode(bytes.fromhex(c["data"])).hex() != c["encoded"]:
            raise SystemExit(f"make_vectors: rodctl.link.protocol COBS disagrees on {c['case']}")


def text(doc: dict) -> str:
    return json.dumps(doc, indent=1) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if the committed JSON is not what this writes")
    args = ap.parse_args(argv)
    doc = document()
    check_against_host_codec(doc)
    t = text(doc)
    if args.check:
        if not OUT.exists() or OUT.read_text() != t:
            print(f"make_vectors: {OUT} is stale; run python3 tests/make_vectors.py", file=sys.stderr)
            return 1
        print(f"up to date: {OUT}")
        return 0
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(t)
    print(f"wrote {OUT} ({len(doc['messages'])} messages, {len(doc['cobs'])} COBS cases)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
