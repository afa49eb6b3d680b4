"""rodlink codec for the host: enums, message tuples, encoders for every message, a streaming Decoder.

Everything here is built at import from firmware/protocol/rodlink.toml (the one definition):
enum members, message fields, struct layouts. Nothing about the layout is typed twice.

    >>> from rodctl.link import protocol as P
    >>> wire = P.encode_arm(P.ArmMode.BALANCE, seq=7)
    >>> P.decode_frame(wire)
    Frame(type=<MsgType.ARM: 17>, seq=7, time_us=0, msg=Arm(mode=<ArmMode.BALANCE: 1>))
    >>> dec = P.Decoder(); frames = dec.feed(serial_bytes)   # never raises; see dec.counters()

Wire format: COBS(header | payload | crc16-LE) 0x00 (see docs/protocol.md).
"""

from __future__ import annotations

import binascii
import enum
import struct
from collections import namedtuple
from typing import Any, NamedTuple

from rodctl.link.protocol_spec import Message, Spec, load_spec

SPEC: Spec = load_spec()

VERSION = SPEC.version
MAX_N = SPEC.max_n
HEADER_SIZE = SPEC.header_size
CRC_SIZE = SPEC.crc_size
MAX_PACKET = SPEC.max_packet
MAX_FRAME = SPEC.max_frame  # on the wire, with the delimiter
CRC_INIT = SPEC.framing["crc_init"]
_MIN_PACKET = HEADER_SIZE + CRC_SIZE
_HEADER_FMT = "<BBII"


class ProtocolError(ValueError):
    """A frame that cannot be decoded (decode_frame); the Decoder counts these instead."""


# ---- enums ------------------------------------------------------------------------------------

def _make_enum(table) -> type[enum.IntEnum]:
    if table.is_flags:
        e = enum.IntFlag(table.python, {c.name: 1 << c.value for c in table.values})
    else:
        e = enum.IntEnum(table.python, {c.name: c.value for c in table.values})
    e.__module__ = __name__
    e.__doc__ = table.doc
    return e


ENUMS: dict[str, type[enum.IntEnum]] = {}
for _t in list(SPEC.codes.values()) + list(SPEC.flags.values()):
    ENUMS[_t.key] = globals()[_t.python] = _make_enum(_t)

MsgType = ENUMS["msg_type"]
Mode = ENUMS["mode"]
Reason = ENUMS["reason"]
AckResult = ENUMS["ack_result"]
ArmMode = ENUMS["arm_mode"]
Param = ENUMS["param"]
TelemetryFlag = ENUMS["telemetry"]
RigFlag = ENUMS["rig"]

# value -> member lookups, so decoding gives enum members for known codes and plain ints otherwise
_CODE_MAPS = {k: {int(m): m for m in e} for k, e in ENUMS.items() if not issubclass(e, enum.IntFlag)}
PARAM_INFO = {Param(c.value): c for c in SPEC.codes["param"].values}  # unit, doc, integer


# ---- messages ---------------------------------------------------------------------------------

class Frame(NamedTuple):
    """One decoded frame: header fields and the message (one of the MESSAGE_CLASSES tuples)."""

    type: int
    seq: int
    time_us: int
    msg: Any


def _public_fields(m: Message):
    return [f for f in m.fields if not f.reserved]


def _make_class(m: Message):
    names = [f.name for f in _public_fields(m)]
    cls = namedtuple(m.class_name, names)
    cls.__module__ = __name__
    cls.TYPE = MsgType[m.name]
    cls.DIRECTION = m.direction
    cls.__doc__ = f"{m.name} ({m.direction.replace('_', ' ')}): {m.doc} Fields: {', '.join(names) or 'none'}."
    return cls


MESSAGE_CLASSES: dict[int, type] = {}
for _m in SPEC.messages:
    MESSAGE_CLASSES[_m.id] = globals()[_m.class_name] = _make_class(_m)

Telemetry = MESSAGE_CLASSES[MsgType.TELEMETRY]
Hello = MESSAGE_CLASSES[MsgType.HELLO]
Ack = MESSAGE_CLASSES[MsgType.ACK]
Heartbeat = MESSAGE_CLASSES[MsgType.HEARTBEAT]
Arm = MESSAGE_CLASSES[MsgType.ARM]
Disarm = MESSAGE_CLASSES[MsgType.DISARM]
ClearFault = MESSAGE_CLASSES[MsgType.CLEAR_FAULT]
Set = MESSAGE_CLASSES[MsgType.SET]
HelloRequest = MESSAGE_CLASSES[MsgType.HELLO_REQUEST]
Identify = MESSAGE_CLASSES[MsgType.IDENTIFY]
SaveRig = MESSAGE_CLASSES[MsgType.SAVE_RIG]

TO_HOST = frozenset(m.id for m in SPEC.messages if m.direction == "to_host")
TO_DEVICE = frozenset(m.id for m in SPEC.messages if m.direction == "to_device")


# ---- layouts ----------------------------------------------------------------------------------

def _payload_format(m: Message, n: int) -> str:
    out = []
    for f in m.fields:
        if f.count is None:
            out.append(f.struct_code)
        elif f.type == "u8" and isinstance(f.count, int):
            out.append(f"{f.count}s")  # fixed byte arrays are bytes
        else:
            k = n if f.variable else f.count
            out.append(f"{k}{f.struct_code}")
    return "".join(out)


_STRUCTS: dict[tuple[int, int], struct.Struct] = {}


def packet_struct(type_id: int, n: int = 0) -> struct.Struct:
    """struct.Struct of a whole packet (header, payload, crc) of this type and n."""
    key = (type_id, n)
    s = _STRUCTS.get(key)
    if s is None:
        m = SPEC.by_id[type_id]
        s = _STRUCTS[key] = struct.Struct(_HEADER_FMT + _payload_format(m, n if m.variable else 0) + "H")
    return s


# ---- COBS -------------------------------------------------------------------------------------

def cobs_encode(data: bytes) -> bytes:
    """COBS without the delimiter; a run of 254 non-zero bytes ending the input takes no extra code."""
    out = bytearray()
    for i, block in enumerate(bytes(data).split(b"\0")):
        last = i == data.count(0)  # the final block has no zero after it
        while len(block) >= 254:
            out.append(0xFF)
            out += block[:254]
            block = block[254:]
            if not block and last:
                return bytes(out)
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of cobs_encode (no delimiter); raises ProtocolError on malformed input."""
    n = len(data)
    if n == 0:
        raise ProtocolError("empty COBS block")
    out = bytearray()
    i = 0
    while i < n:
        code = data[i]
        end = i + code
        if code == 0 or end > n:
            raise ProtocolError("malformed COBS")
        block = data[i + 1:end]
        if 0 in block:
            raise ProtocolError("zero byte inside a COBS block")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: crc16(b"123456789") == 0x29B1."""
    return binascii.crc_hqx(data, CRC_INIT)


# ---- encoding ---------------------------------------------------------------------------------

def _packet_values(m: Message, msg) -> tuple[list, int]:
    vals, n = [], 0
    if m.variable:
        n = getattr(msg, m.count_field)
        if not (0 <= n <= MAX_N):
            raise ValueError(f"{m.name}: {m.count_field} = {n} not in 0..{MAX_N}")
    for f in m.fields:
        if f.reserved:
            vals.append(f.value)
            continue
        v = getattr(msg, f.name)
        if f.count is None:
            vals.append(v)
        elif f.type == "u8" and isinstance(f.count, int):
            v = bytes(v)
            if len(v) != f.count:
                raise ValueError(f"{m.name}.{f.name}: {len(v)} bytes, expected {f.count}")
            vals.append(v)
        else:
            k = n if f.variable else f.count
            v = tuple(v)
            if len(v) != k:
                raise ValueError(f"{m.name}.{f.name}: {len(v)} values, expected {k}")
            vals.extend(v)
    return vals, n


def encode_packet(type_id: int, seq: int, time_us: int, payload: bytes) -> bytes:
    """The wire frame for any header + raw payload (tests use it to build malformed commands)."""
    body = struct.pack(_HEADER_FMT, VERSION, type_id, seq & 0xFFFFFFFF, time_us & 0xFFFFFFFF) + bytes(payload)
    return cobs_encode(body + crc16(body).to_bytes(2, "little")) + b"\0"


def encode(msg, seq: int, time_us: int = 0) -> bytes:
    """The complete wire frame (COBS + 0x00) of one message tuple."""
    m = SPEC.by_id[msg.TYPE]
    vals, n = _packet_values(m, msg)
    s = packet_struct(m.id, n)
    try:
        body = s.pack(VERSION, m.id, seq & 0xFFFFFFFF, time_us & 0xFFFFFFFF, *vals, 0)[:-CRC_SIZE]
    except (struct.error, OverflowError) as e:
        raise ValueError(f"{m.name}: a field does not fit its type: {e}") from None
    return cobs_encode(body + crc16(body).to_bytes(2, "little")) + b"\0"


def _make_encoder(cls):
    def enc(*args, seq: int, time_us: int = 0, **fields) -> bytes:
        msg = args[0] if len(args) == 1 and not fields and isinstance(args[0], cls) else cls(*args, **fields)
        return encode(msg, seq, time_us)

    m = SPEC.by_id[cls.TYPE]
    enc.__name__ = enc.__qualname__ = f"encode_{m.name.lower()}"
    enc.__doc__ = (f"Wire frame of {m.name}: encode_{m.name.lower()}({', '.join(cls._fields + ('',))}"
                   f"*, seq, time_us=0), or pass one {cls.__name__} tuple.")
    return enc


for _cls in MESSAGE_CLASSES.values():
    _f = _make_encoder(_cls)
    globals()[_f.__name__] = _f

encode_telemetry = globals()["encode_telemetry"]
encode_hello = globals()["encode_hello"]
encode_ack = globals()["encode_ack"]
encode_heartbeat = globals()["encode_heartbeat"]
encode_arm = globals()["encode_arm"]
encode_disarm = globals()["encode_disarm"]
encode_clear_fault = globals()["encode_clear_fault"]
encode_set = globals()["encode_set"]
encode_hello_request = globals()["encode_hello_request"]


# ---- decoding ---------------------------------------------------------------------------------
#
# Per message type one small function, generated from the TOML, turns the unpacked packet tuple
# into the message tuple (skipping reserved fields, slicing the arrays, mapping codes to enums).

def _decoder_source(m: Message) -> str:
    lines = [f"def _dec_{m.name}(ba, plen):"]
    idx = 4  # after version, type, seq, time_us
    parts = []
    if m.variable:
        cf = m.field(m.count_field)
        lines.append(f"    if plen < {_MIN_PACKET + m.size_fixed}:")  # the count byte itself may be missing
        lines.append("        return None")
        lines.append(f"    n = ba[{1 + HEADER_SIZE + cf.offset}]")
        lines.append(f"    if n > {MAX_N} or plen != {_MIN_PACKET + m.size_fixed} + {m.size_per_n} * n:")
        lines.append("        return None")
        lines.append(f"    v = _struct({m.id}, n).unpack_from(ba, 1)")
    else:
        lines.append(f"    if plen != {_MIN_PACKET + m.size_fixed}:")
        lines.append("        return None")
        lines.append(f"    v = _S{m.id}.unpack_from(ba, 1)")
    pos = idx  # fixed index while no variable array has been passed
    var_k = 0  # variable arrays passed (each adds n to the index)

    def at(k: int) -> str:
        return f"{k} + {var_k} * n" if var_k else str(k)

    for f in m.fields:
        if f.count is None or (f.type == "u8" and isinstance(f.count, int)):
            if not f.reserved:
                expr = f"v[{at(pos)}]"
                if f.codes and f.codes in _CODE_MAPS:
                    expr = f"_C_{f.codes}.get({expr}, {expr})"
                parts.append(expr)
            pos += 1
        elif f.variable:
            parts.append(f"v[{at(pos)}:{pos} + {var_k + 1} * n]")
            var_k += 1
        else:
            parts.append(f"v[{at(pos)}:{at(pos + f.count)}]")
            pos += f.count
    tup = "(" + ", ".join(parts) + ("," if len(parts) == 1 else "") + ")"
    lines.append(f"    return _Frame(_T{m.id}, v[2], v[3], _new(_C{m.id}, {tup}))")
    return "\n".join(lines) + "\n"


def _build_decoders() -> dict[int, Any]:
    ns: dict[str, Any] = {"_struct": packet_struct, "_Frame": Frame, "_new": tuple.__new__}
    for k, mp in _CODE_MAPS.items():
        ns[f"_C_{k}"] = mp
    out = {}
    for m in SPEC.messages:
        ns[f"_T{m.id}"] = MsgType(m.id)
        ns[f"_C{m.id}"] = MESSAGE_CLASSES[m.id]
        if not m.variable:
            ns[f"_S{m.id}"] = packet_struct(m.id)
        exec(compile(_decoder_source(m), f"<rodlink decoder {m.name}>", "exec"), ns)  # noqa: S102
        out[m.id] = ns[f"_dec_{m.name}"]
    return out


_DECODERS = _build_decoders()

# error kinds of _decode_raw
_E_FRAMING, _E_CRC, _E_VERSION, _E_UNKNOWN, _E_LENGTH = range(1, 6)
_ERROR_TEXT = {_E_FRAMING: "bad COBS or packet too short/long", _E_CRC: "CRC mismatch",
               _E_VERSION: "wrong protocol version", _E_UNKNOWN: "unknown message type",
               _E_LENGTH: "payload length does not fit the type"}
_crc_hqx = binascii.crc_hqx


def _cobs_to_packet(f: bytes) -> bytearray | None:
    """COBS block (no delimiter, no zero bytes) -> bytearray whose [1:] is the packet, or None."""
    L = len(f)
    if L < 255:
        # Fast path: no 0xFF code fits, so every code but the last stands for a zero: zero it in place.
        ba = bytearray(f)
        i = ba[0]
        while i < L:
            c = ba[i]
            ba[i] = 0
            i += c
        return ba if i == L else None
    try:
        return bytearray(b"\1" + cobs_decode(f))
    except ProtocolError:
        return None


def _decode_raw(f: bytes):
    """Frame, or an _E_* error code, for one COBS block taken from between two delimiters."""
    if len(f) > MAX_FRAME:
        return _E_FRAMING
    ba = _cobs_to_packet(f)
    if ba is None:
        return _E_FRAMING
    plen = len(ba) - 1
    if plen < _MIN_PACKET or plen > MAX_PACKET:
        return _E_FRAMING
    if _crc_hqx(ba[1:-2], CRC_INIT) != ba[-2] | (ba[-1] << 8):
        return _E_CRC
    if ba[1] != VERSION:
        return _E_VERSION
    dec = _DECODERS.get(ba[2])
    if dec is None:
        return _E_UNKNOWN
    try:
        fr = dec(ba, plen)
    except (IndexError, struct.error, ValueError):  # never raise on input: a decoder bug costs one frame
        return _E_LENGTH
    return _E_LENGTH if fr is None else fr


def decode_frame(frame: bytes) -> Frame:
    """Decode exactly one frame (with or without its 0x00); raises ProtocolError."""
    frame = bytes(frame)
    if frame.endswith(b"\0"):
        frame = frame[:-1]
    if not frame or 0 in frame:
        raise ProtocolError("not one COBS frame")
    r = _decode_raw(frame)
    if isinstance(r, int):
        raise ProtocolError(_ERROR_TEXT[r])
    return r


class Decoder:
    """Streaming decoder: feed() any bytes, get the complete valid frames; never raises on input.

    Counters: frames (decoded), crc_errors, framing_errors (bad COBS, too short, too long),
    version_errors, unknown_type (CRC-valid, type not in the protocol), length_errors (known type,
    payload length wrong), seq_gaps (device->host frames missing per the sequence numbers, which the
    device assigns to all its frames from one counter), seq_restarts (sequence went backwards, e.g.
    a device reset), bytes. A damaged frame costs only itself: decoding resumes at the next 0x00.
    """

    COUNTERS = ("frames", "crc_errors", "framing_errors", "version_errors", "unknown_type", "length_errors",
                "seq_gaps", "seq_restarts", "bytes")

    def __init__(self) -> None:
        for c in self.COUNTERS:
            setattr(self, c, 0)
        self._pending = b""
        self._discarding = False
        self.last_seq: int | None = None

    def counters(self) -> dict[str, int]:
        return {c: getattr(self, c) for c in self.COUNTERS}

    @property
    def errors(self) -> int:
        """Frames dropped as damaged or not understood."""
        return self.crc_errors + self.framing_errors + self.version_errors + self.unknown_type + self.length_errors

    def reset_seq(self) -> None:
        """Forget the last sequence number (e.g. after reopening the port)."""
        self.last_seq = None

    def feed(self, data: bytes) -> list[Frame]:
        try:
            data = bytes(data)
        except Exception:  # noqa: BLE001 - never raise on input
            self.framing_errors += 1
            return []
        self.bytes += len(data)
        parts = (self._pending + data).split(b"\0") if self._pending else data.split(b"\0")
        tail = parts.pop()
        if self._discarding:
            if not parts:
                return []  # still inside an oversize frame
            parts[0] = b""  # its end: already counted
            self._discarding = False
        if len(tail) >= MAX_FRAME:  # no delimiter can make this a valid frame
            self.framing_errors += 1
            self._discarding = True
            tail = b""
        self._pending = tail

        out: list[Frame] = []
        append = out.append
        decode = _decode_raw
        to_host = TO_HOST
        last = self.last_seq
        for f in parts:
            if not f:
                continue  # back-to-back delimiters: idle line
            r = decode(f)
            if r.__class__ is not Frame:
                if r == _E_CRC:
                    self.crc_errors += 1
                elif r == _E_FRAMING:
                    self.framing_errors += 1
                elif r == _E_VERSION:
                    self.version_errors += 1
                elif r == _E_UNKNOWN:
                    self.unknown_type += 1
                else:
                    self.length_errors += 1
                continue
            if r[0] in to_host:
                seq = r[1]
                if last is not None:
                    gap = (seq - last - 1) & 0xFFFFFFFF
                    if gap < 0x80000000:
                        self.seq_gaps += gap
                    else:
                        self.seq_restarts += 1
                last = seq
            append(r)
        self.last_seq = last
        self.frames += len(out)
        return out
