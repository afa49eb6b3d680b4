"""Vectorized decoding of many TELEMETRY frames at once (numpy), for captures and benchmarks.

    cols, counters = decode_telemetry(buffer, n=5)
    cols["theta_hat"]          # (frames, n) float32 [rad]; cols["seq"], cols["time_us"], ... 1-D arrays

The same checks as protocol.Decoder (COBS, length, CRC-16/CCITT-FALSE, version, type, n), done on a
(frames x bytes) matrix instead of frame by frame: every frame of the one TELEMETRY length is decoded
in a few dozen numpy operations. Frames of other lengths (HELLO, ACK, other n) are counted in
counters["other"], not decoded: feed those to protocol.Decoder. Bytes after the last 0x00 are left
(counters["consumed"] tells how many bytes were used).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from rodctl.link import protocol as P

_NP = {"u8": "u1", "i8": "i1", "u16": "<u2", "i16": "<i2", "u32": "<u4", "i32": "<i4", "f32": "<f4"}
_POLY = 0x1021
BLOCK = 32768  # frames per block


def _crc_table16() -> np.ndarray:
    """T[x] = the CRC register after shifting 16 zero bits through register x (two bytes per lookup)."""
    x = np.arange(1 << 16, dtype=np.uint32)
    for _ in range(16):
        x = np.where(x & 0x8000, (x << 1) ^ _POLY, x << 1) & 0xFFFF
    return x.astype(np.uint16)


def _crc_table8() -> np.ndarray:
    x = np.arange(256, dtype=np.uint32) << 8
    for _ in range(8):
        x = np.where(x & 0x8000, (x << 1) ^ _POLY, x << 1) & 0xFFFF
    return x.astype(np.uint16)


_T16 = _crc_table16()
_T8 = _crc_table8()


def crc16_rows(data: np.ndarray) -> np.ndarray:
    """CRC-16/CCITT-FALSE of every row of a (frames, bytes) uint8 matrix (== protocol.crc16 per row)."""
    rows, k = data.shape
    crc = np.full(rows, P.CRC_INIT, dtype=np.uint16)
    # Big-endian 16-bit words, one contiguous row per word position: each lookup streams through memory.
    words = np.ascontiguousarray(data[:, : k - k % 2]).view(">u2").T.copy()
    for w in words:
        crc = _T16[crc ^ w]
    if k % 2:
        crc = (crc << 8) ^ _T8[(crc >> 8) ^ data[:, -1]]
    return crc


def _cobs_in_place(enc: np.ndarray) -> np.ndarray:
    """Zero every code byte of a (frames, L) matrix of COBS blocks; returns where each chain ended (L if valid)."""
    F, L = enc.shape
    flat = enc.reshape(-1)
    end = np.zeros(F, dtype=np.int32)
    live = np.arange(F, dtype=np.int32)
    base = live * L
    pos = np.zeros(F, dtype=np.int32)
    while live.size:
        fi = base + pos
        c = flat[fi]
        flat[fi] = 0
        pos += c
        keep = (pos < L) & (c > 0)
        if not keep.all():
            end[live[~keep]] = np.where(c[~keep] > 0, pos[~keep], -1)
            live, pos, base = live[keep], pos[keep], base[keep]
    return end


def packet_dtype(n: int) -> np.dtype:
    """numpy dtype of one whole TELEMETRY packet with n edges (header, payload fields, crc)."""
    m = P.SPEC.by_id[int(P.MsgType.TELEMETRY)]
    fields = [("version", "u1"), ("type", "u1"), ("seq", "<u4"), ("time_us", "<u4")]
    for f in m.fields:
        if f.count is None:
            fields.append((f.name, _NP[f.type]))
        else:
            fields.append((f.name, _NP[f.type], (n if f.variable else f.count,)))
    fields.append(("crc", "<u2"))
    dt = np.dtype(fields)
    assert dt.itemsize == P.packet_struct(int(P.MsgType.TELEMETRY), n).size
    return dt


def decode_telemetry(buf, n: int) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """(columns, counters) of every n-edge TELEMETRY frame in `buf` (bytes-like, frames ending in 0x00)."""
    dt = packet_dtype(n)
    plen = dt.itemsize
    if plen + 1 >= 255:
        raise ValueError(f"n = {n}: packets of {plen} bytes need the scalar decoder (COBS 0xFF blocks)")
    a = np.frombuffer(buf, dtype=np.uint8)
    zeros = np.flatnonzero(a == 0)
    counters = {"frames": 0, "crc_errors": 0, "other": 0,
                "consumed": int(zeros[-1]) + 1 if zeros.size else 0}
    starts = np.concatenate([[0], zeros[:-1] + 1]) if zeros.size else np.zeros(0, dtype=np.int64)
    lengths = zeros - starts
    mine = lengths == plen + 1
    counters["other"] = int(np.count_nonzero(~mine & (lengths > 0)))
    s = starts[mine]
    win = sliding_window_view(a, plen + 1)
    pkts, oks = [], []
    for i in range(0, len(s), BLOCK):  # blocks that fit the cache: several times faster than all at once
        enc = win[s[i:i + BLOCK]]  # (frames, COBS bytes), a copy
        ok = _cobs_in_place(enc) == plen + 1
        pkt = enc[:, 1:]
        crc = crc16_rows(pkt[:, :-2])
        ok &= crc == (pkt[:, -2].astype(np.uint16) | (pkt[:, -1].astype(np.uint16) << 8))
        pkts.append(pkt)
        oks.append(ok)
    pkt = np.ascontiguousarray(np.concatenate(pkts)) if pkts else np.zeros((0, plen), dtype=np.uint8)
    ok = np.concatenate(oks) if oks else np.zeros(0, dtype=bool)
    counters["crc_errors"] = int(np.count_nonzero(~ok))  # COBS or CRC: the frame is damaged either way
    rec = pkt.view(dt).reshape(-1)
    good = ok & (rec["version"] == P.VERSION) & (rec["type"] == int(P.MsgType.TELEMETRY)) & (rec["n"] == n)
    counters["other"] += int(np.count_nonzero(ok & ~good))
    rec = rec[good]
    counters["frames"] = len(rec)
    cols = {name: rec[name] for name in dt.names if name not in ("version", "type", "crc")
            and not name.startswith("reserved")}
    return cols, counters
