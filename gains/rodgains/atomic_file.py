"""Files written whole or not at all: a reader (another process, another host on a shared folder, a
user's tool) sees the old file or the new one, never half of one."""

from __future__ import annotations

import os
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Yield a temporary name beside `path` to write; on success it replaces `path` in one rename, on
    error it is removed and `path` is left as it was. The name is unique per process, thread and host."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write(path: str | Path, data: str | bytes) -> Path:
    """Write text (UTF-8) or bytes to `path` atomically; returns the path."""
    with replacing(path) as tmp:
        tmp.write_bytes(data.encode() if isinstance(data, str) else data)
    return Path(path)


def stale(files: dict[Path, str], comparable: Callable[[str], object] | None = None) -> list[Path]:
    """Of generated files ({path: text}), those missing or not holding their text (as UTF-8: a file that is not
    text is stale, not an error). comparable(text): what of a text must match (default: all of it, byte for byte)."""
    def held(f: Path, text: str) -> bool:
        data = f.read_bytes()
        if data == text.encode():
            return True
        try:
            return comparable is not None and comparable(data.decode("utf-8")) == comparable(text)
        except UnicodeDecodeError:
            return False

    return [f for f, text in files.items() if not f.is_file() or not held(f, text)]


def write_changed(files: dict[Path, str]) -> list[Path]:
    """Write each generated file ({path: text}) that is stale, atomically; returns those written."""
    written = stale(files)
    for f in written:
        atomic_write(f, files[f])
    return written
