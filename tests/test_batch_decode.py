"""The vectorized telemetry decoder (link/batch.py) agrees with the streaming Decoder, damage included."""

from __future__ import annotations

import random

import numpy as np

from rodctl.bench.protocol import telemetry_stream
from rodctl.link import batch
from rodctl.link import protocol as P


def test_crc_of_rows_matches_the_scalar_crc():
    rng = np.random.default_rng(3)
    for k in (1, 2, 7, 64):
        data = rng.integers(0, 256, size=(50, k), dtype=np.uint8)
        assert list(batch.crc16_rows(data)) == [P.crc16(bytes(r)) for r in data]


def test_batch_decode_equals_the_streaming_decoder_on_a_damaged_mixed_stream():
    rng = random.Random(5)
    blob = bytearray(telemetry_stream(3000, 5))
    hello = P.Hello(0, 1, 0, 1, 5, P.Mode.DISARMED, P.Reason.NONE, 0, 1000, 1, 0.01, 0.5, 0.5, 0.5, 0.2, bytes(32), 4896, 5)
    blob += P.encode_hello(hello, seq=9999) + P.encode_ack(P.MsgType.ARM, P.AckResult.OK, 1, P.Mode.CATCH, seq=10000)
    for _ in range(40):  # flipped bits and bytes anywhere (a flipped byte may also make a new delimiter)
        i = rng.randrange(len(blob))
        blob[i] = rng.randrange(256)
    blob += blob[:37]  # and a cut frame at the end
    cols, counters = batch.decode_telemetry(bytes(blob), 5)
    frames = [f for f in P.Decoder().feed(bytes(blob)) if f.type == P.MsgType.TELEMETRY and f.msg.n == 5]
    assert counters["frames"] == len(frames) > 2900
    assert np.array_equal(cols["seq"], [f.seq for f in frames])
    assert np.array_equal(cols["time_us"], [f.time_us for f in frames])
    assert np.array_equal(cols["encoder_count"], [f.msg.encoder_count for f in frames])
    assert np.array_equal(cols["theta_hat"], np.array([f.msg.theta_hat for f in frames], dtype=np.float32))
    assert np.array_equal(cols["rate_hat"], np.array([f.msg.rate_hat for f in frames], dtype=np.float32))
    assert np.array_equal(cols["mode"], [int(f.msg.mode) for f in frames])
    assert counters["consumed"] == blob.rindex(0) + 1
