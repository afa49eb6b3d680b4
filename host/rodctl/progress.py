"""Progress bars on stderr for long work: tqdm's redrawn bar on a terminal; elsewhere (a log file, a pipe,
CI) whole lines, fewer of them, so that a log reads line by line instead of as one line of carriage returns."""

from __future__ import annotations

import sys


class _Lines:
    """A stream for tqdm off a terminal: each redraw becomes its own line."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str) -> None:
        text = text.replace("\r", "").replace("\x1b[A", "")
        if text.strip():
            self.stream.write(text.rstrip("\n") + "\n")

    def flush(self) -> None:
        self.stream.flush()


def bar(*, total: int | None, desc: str, unit: str, initial: int = 0, leave: bool = True):
    """A tqdm bar on stderr: redrawn at most 5 times a second on a terminal, else a line every 10 s."""
    from tqdm import tqdm

    tty = sys.stderr.isatty()
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=sys.stderr if tty else _Lines(sys.stderr),
                dynamic_ncols=tty, ncols=None if tty else 100, mininterval=0.2 if tty else 10.0,
                leave=leave if tty else True)
