"""Load and check firmware/protocol/rodlink.toml, the one definition of the rodlink wire protocol.

Computes every payload layout (offsets are never written by hand: fields are packed in order).
Used by host/rodctl/link/protocol.py (codec) and host/rodctl/link/protocol_gen.py (C header and docs generator).
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

from rodgains.errors import UserError

from rodctl import paths

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

SPEC_PATH = paths.SPEC

# wire type -> (struct code, size in bytes, C type)
TYPES = {
    "u8": ("B", 1, "uint8_t"),
    "u16": ("H", 2, "uint16_t"),
    "u32": ("I", 4, "uint32_t"),
    "i32": ("i", 4, "int32_t"),
    "f32": ("f", 4, "float"),
}
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_UPPER = re.compile(r"^[A-Z][A-Z0-9_]*$")


class SpecError(UserError):
    """rodlink.toml is malformed or inconsistent."""

    exit_code = 2


@dataclass(frozen=True)
class Code:
    name: str
    value: int
    doc: str = ""
    unit: str = ""
    integer: bool = False
    min: float | None = None  # physical range of a SET parameter, inclusive, in `unit`
    max: float | None = None
    design_max: str | None = None  # rod_gains.h macro that lowers max (e.g. ROD_TORQUE_MAX_NM)


@dataclass(frozen=True)
class CodeTable:
    key: str
    doc: str
    c_prefix: str
    python: str
    values: tuple[Code, ...]
    is_flags: bool = False  # values are bit numbers

    def by_name(self, name: str) -> Code:
        for c in self.values:
            if c.name == name:
                return c
        raise KeyError(name)


@dataclass(frozen=True)
class Field:
    name: str
    type: str
    doc: str = ""
    unit: str = ""
    count: int | str | None = None  # None: scalar; int: fixed array; str: variable, length = that field
    value: int | None = None  # pinned value (reserved bytes, version)
    codes: str | None = None
    flags: str | None = None
    offset: int = 0  # offset = offset + offset_per_n * n
    offset_per_n: int = 0

    @property
    def struct_code(self) -> str:
        return TYPES[self.type][0]

    @property
    def elem_size(self) -> int:
        return TYPES[self.type][1]

    @property
    def c_type(self) -> str:
        return TYPES[self.type][2]

    @property
    def reserved(self) -> bool:
        return self.value is not None

    @property
    def variable(self) -> bool:
        return isinstance(self.count, str)

    def size(self, n: int = 0) -> int:
        if self.count is None:
            return self.elem_size
        k = n if self.variable else self.count
        return self.elem_size * k


@dataclass(frozen=True)
class Message:
    name: str
    id: int
    direction: str  # "to_host" | "to_device"
    doc: str
    fields: tuple[Field, ...]
    size_fixed: int  # payload size = size_fixed + size_per_n * n
    size_per_n: int
    count_field: str | None  # the u8 field that gives n, for variable layouts

    @property
    def variable(self) -> bool:
        return self.count_field is not None

    def payload_size(self, n: int = 0) -> int:
        return self.size_fixed + self.size_per_n * n

    @property
    def class_name(self) -> str:
        return "".join(part.capitalize() for part in self.name.split("_"))

    def field(self, name: str) -> Field:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(name)


@dataclass(frozen=True)
class Spec:
    path: Path
    sha256: str
    text: str
    name: str
    version: int
    max_n: int
    framing: dict
    header: tuple[Field, ...]
    header_size: int
    crc_size: int
    codes: dict[str, CodeTable]
    flags: dict[str, CodeTable]
    messages: tuple[Message, ...]
    by_id: dict[int, Message] = field(repr=False)
    by_name: dict[str, Message] = field(repr=False)

    @property
    def max_payload(self) -> int:
        return max(m.payload_size(self.max_n if m.variable else 0) for m in self.messages)

    @property
    def max_packet(self) -> int:
        return self.header_size + self.max_payload + self.crc_size

    @staticmethod
    def cobs_max(n: int) -> int:
        """Safe upper bound of the COBS encoding of n bytes (= the C macro ROD_COBS_MAX_ENCODED)."""
        return n + n // 254 + 1

    @property
    def max_frame(self) -> int:
        return self.cobs_max(self.max_packet) + 1


def _err(where: str, what: str) -> SpecError:
    return SpecError(f"rodlink.toml: {where}: {what}")


def _get(d: dict, key: str, kind, where: str, default=None, required=True):
    if key not in d:
        if required:
            raise _err(where, f"missing {key!r}")
        return default
    v = d[key]
    if kind is int and (isinstance(v, bool) or not isinstance(v, int)):
        raise _err(where, f"{key!r} must be an integer")
    if kind is not int and not isinstance(v, kind):
        raise _err(where, f"{key!r} must be {kind.__name__}")
    return v


def _number(d: dict, key: str, where: str) -> float | None:
    v = d.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or abs(v) == float("inf"):
        raise _err(where, f"{key!r} must be a finite number")
    return float(v)


def _check_keys(d: dict, allowed: set[str], where: str) -> None:
    extra = sorted(set(d) - allowed)
    if extra:
        raise _err(where, f"unknown key(s) {', '.join(extra)}")


def _code_table(key: str, d: dict, is_flags: bool) -> CodeTable:
    where = f"{'flags' if is_flags else 'codes'}.{key}"
    list_key = "bits" if is_flags else "values"
    _check_keys(d, {"doc", "c_prefix", "python", list_key}, where)
    out, names, nums = [], set(), set()
    for i, c in enumerate(_get(d, list_key, list, where)):
        w = f"{where}.{list_key}[{i}]"
        _check_keys(c, {"name", "bit" if is_flags else "value", "doc", "unit", "integer", "min", "max",
                        "design_max"}, w)
        name = _get(c, "name", str, w)
        value = _get(c, "bit" if is_flags else "value", int, w)
        if not _UPPER.match(name):
            raise _err(w, f"name {name!r} must be UPPER_CASE")
        if name in names or value in nums:
            raise _err(w, f"duplicate name or value ({name}, {value})")
        if not (0 <= value <= (7 if is_flags else 255)):
            raise _err(w, f"{value} does not fit a u8{' bit' if is_flags else ''}")
        names.add(name)
        nums.add(value)
        lo, hi = (_number(c, k, w) for k in ("min", "max"))
        design_max = _get(c, "design_max", str, w, None, False)
        if design_max is not None and not _UPPER.match(design_max):
            raise _err(w, f"design_max {design_max!r} must name a rod_gains.h macro")
        if (lo is None) != (hi is None and design_max is None) or (lo is not None and hi is not None and not lo < hi):
            raise _err(w, "a range needs min and max (or design_max), with min < max")
        out.append(Code(name, value, _get(c, "doc", str, w, "", False), _get(c, "unit", str, w, "", False),
                        _get(c, "integer", bool, w, False, False), lo, hi, design_max))
    return CodeTable(key, _get(d, "doc", str, where, "", False), _get(d, "c_prefix", str, where),
                     _get(d, "python", str, where), tuple(out), is_flags)


def _layout(raw: list, where: str, codes: dict, flags: dict) -> tuple[tuple[Field, ...], int, int, str | None]:
    fields: list[Field] = []
    off, per_n, count_field = 0, 0, None
    seen: dict[str, Field] = {}
    for i, f in enumerate(raw):
        w = f"{where}.fields[{i}]"
        _check_keys(f, {"name", "type", "doc", "unit", "count", "value", "codes", "flags"}, w)
        name = _get(f, "name", str, w)
        typ = _get(f, "type", str, w)
        if not _NAME.match(name) or name != name.lower():
            raise _err(w, f"field name {name!r} must be lower_case")
        if name in seen:
            raise _err(w, f"duplicate field {name!r}")
        if typ not in TYPES:
            raise _err(w, f"type {typ!r} is not one of {', '.join(TYPES)}")
        count = f.get("count")
        if count is not None:
            if isinstance(count, str):
                ref = seen.get(count)
                if ref is None or ref.type != "u8" or ref.count is not None:
                    raise _err(w, f"count {count!r} must name an earlier scalar u8 field")
                if count_field not in (None, count):
                    raise _err(w, "all variable arrays of a message must share one count field")
                count_field = count
            elif isinstance(count, bool) or not isinstance(count, int) or count < 1:
                raise _err(w, "count must be a positive integer or a field name")
        cod = _get(f, "codes", str, w, None, False)
        if cod is not None and cod not in codes:
            raise _err(w, f"unknown code table {cod!r}")
        flg = _get(f, "flags", str, w, None, False)
        if flg is not None and flg not in flags:
            raise _err(w, f"unknown flags table {flg!r}")
        value = _get(f, "value", int, w, None, False)
        fld = Field(name, typ, _get(f, "doc", str, w, "", False), _get(f, "unit", str, w, "", False),
                    count, value, cod, flg, off, per_n)
        fields.append(fld)
        seen[name] = fld
        if isinstance(count, str):
            per_n += fld.elem_size
        else:
            off += fld.size()
    return tuple(fields), off, per_n, count_field


def _load(path: Path) -> Spec:
    try:
        raw_bytes = path.read_bytes()
    except OSError as e:
        raise SpecError(f"cannot read the protocol definition {path}: {e.strerror}") from None
    try:
        d = tomllib.loads(raw_bytes.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise SpecError(f"rodlink.toml: not valid TOML: {e}") from None
    _check_keys(d, {"protocol", "framing", "header", "codes", "flags", "messages"}, "top level")
    p = _get(d, "protocol", dict, "top level")
    _check_keys(p, {"name", "version", "max_n", "byte_order"}, "protocol")
    version = _get(p, "version", int, "protocol")
    max_n = _get(p, "max_n", int, "protocol")
    if _get(p, "byte_order", str, "protocol") != "little":
        raise _err("protocol", "only byte_order = \"little\" is supported")
    if not (1 <= version <= 255 and 1 <= max_n <= 255):
        raise _err("protocol", "version and max_n must be 1..255")
    framing = _get(d, "framing", dict, "top level")
    for k, v in {"encoding": "COBS", "delimiter": 0, "crc_poly": 0x1021, "crc_reflected": False,
                 "crc_xorout": 0}.items():
        if framing.get(k) != v:
            raise _err("framing", f"{k} must be {v!r} (the codecs implement only that)")
    for k in ("crc_init", "crc_check"):
        _get(framing, k, int, "framing")

    codes = {k: _code_table(k, v, False) for k, v in _get(d, "codes", dict, "top level").items()}
    flags = {k: _code_table(k, v, True) for k, v in _get(d, "flags", dict, "top level", {}, False).items()}
    if "msg_type" not in codes:
        raise _err("codes", "missing the msg_type table")

    h = _get(d, "header", dict, "top level")
    header, header_size, h_per_n, _ = _layout(_get(h, "fields", list, "header"), "header", codes, flags)
    expect = [("version", "u8"), ("type", "u8"), ("seq", "u32"), ("time_us", "u32")]
    if [(f.name, f.type) for f in header] != expect or h_per_n:
        raise _err("header", "must be version u8, type u8, seq u32, time_us u32 (the codecs implement that)")
    if header[0].value != version:
        raise _err("header", "version field's value must equal protocol.version")

    messages = []
    ids = {c.name: c.value for c in codes["msg_type"].values}
    for i, m in enumerate(_get(d, "messages", list, "top level")):
        w = f"messages[{i}]"
        _check_keys(m, {"name", "direction", "doc", "fields"}, w)
        name = _get(m, "name", str, w)
        w = f"message {name}"
        if name not in ids:
            raise _err(w, "has no code in codes.msg_type")
        direction = _get(m, "direction", str, w)
        if direction not in ("to_host", "to_device"):
            raise _err(w, "direction must be to_host or to_device")
        fields, size, per_n, count_field = _layout(_get(m, "fields", list, w), w, codes, flags)
        messages.append(Message(name, ids[name], direction, _get(m, "doc", str, w, "", False), fields,
                                size, per_n, count_field))
    names = [m.name for m in messages]
    if sorted(names) != sorted(ids) or len(set(names)) != len(names):
        raise _err("messages", "must define each codes.msg_type entry exactly once")
    text = raw_bytes.decode("utf-8")
    return Spec(path=path, sha256=hashlib.sha256(raw_bytes).hexdigest(), text=text, name=_get(p, "name", str, "protocol"),
                version=version, max_n=max_n, framing=framing, header=header, header_size=header_size, crc_size=2,
                codes=codes, flags=flags, messages=tuple(messages), by_id={m.id: m for m in messages},
                by_name={m.name: m for m in messages})


@lru_cache(maxsize=8)
def _load_cached(path: str, mtime_ns: int, size: int) -> Spec:
    return _load(Path(path))


def load_spec(path: str | Path | None = None) -> Spec:
    """The protocol definition (default: the checkout's firmware/protocol/rodlink.toml)."""
    p = Path(path) if path else SPEC_PATH
    try:
        st = p.stat()
    except OSError:
        return _load(p)  # raises a one-line SpecError
    return _load_cached(str(p.resolve()), st.st_mtime_ns, st.st_size)
