"""Proof that the firmware core builds for the Teensy's Cortex-M4F exactly as it must.

Compiles every firmware/src/core/*.c with arm-none-eabi-gcc and the target's flags against a
given rod_gains.h, and fails on any warning or on any reference to a soft-double helper
(`__aeabi_d*`: a `double` slipped in, which the single-precision FPU cannot run). Reports the
core's flash (text+data) and RAM (data+bss) from arm-none-eabi-size, per object and as linked
with --gc-sections from the board-facing API (what actually lands in the Teensy image).

    python -m rodctl.build.target_build [--header build/n20/rod_gains.h]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from rodgains.errors import UserError

from rodctl import paths

CC = "arm-none-eabi-gcc"
NM = "arm-none-eabi-nm"
SIZE = "arm-none-eabi-size"

# The target flags of the firmware brief; PlatformIO's teensy35 build uses the same CPU flags.
TARGET_FLAGS = (
    "-std=c11", "-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard",
    "-O2", "-fsingle-precision-constant", "-ffunction-sections", "-fdata-sections",
    "-Wall", "-Wextra", "-Wdouble-promotion", "-Werror",
)

# What the board calls: everything the linked image must keep.
BOARD_API = ("rod_device_init", "rod_device_step", "rod_device_rx", "rod_device_tx", "rod_device_count_tx_drop")

_ENTRY_C = """\
#include "rod_device.h"
/* Keeps the device instance's size visible to nm -S (RAM the board allocates). */
rod_device_t rod_target_device;
"""


@dataclass
class TargetBuild:
    header: Path
    objects: dict[str, dict[str, int]] = field(default_factory=dict)  # name -> text/data/bss
    linked: dict[str, int] = field(default_factory=dict)  # text/data/bss of the gc-linked core
    device_bytes: int = 0  # sizeof(rod_device_t)

    @property
    def object_flash(self) -> int:
        return sum(o["text"] + o["data"] for o in self.objects.values())

    @property
    def object_ram(self) -> int:
        return sum(o["data"] + o["bss"] for o in self.objects.values())

    @property
    def flash_bytes(self) -> int:
        """Flash of the core as linked (text+data), libc/libm helpers it pulls in included."""
        return self.linked["text"] + self.linked["data"]

    @property
    def ram_bytes(self) -> int:
        """Static RAM of the core as linked (data+bss), including one rod_device_t."""
        return self.linked["data"] + self.linked["bss"]

    def to_json(self) -> dict:
        return {
            "header": str(self.header),
            "objects": self.objects,
            "object_flash_bytes": self.object_flash,
            "object_ram_bytes": self.object_ram,
            "linked": self.linked,
            "flash_bytes": self.flash_bytes,
            "ram_bytes": self.ram_bytes,
            "device_bytes": self.device_bytes,
        }


def _need(tool: str) -> str:
    path = shutil.which(tool)
    if path is None:
        raise UserError(f"{tool} not found: install the ARM toolchain (Debian: apt-get install gcc-arm-none-eabi "
                        "libnewlib-arm-none-eabi)")
    return path


def _run(cmd: list[str], what: str) -> str:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        msg = (r.stderr.strip() or r.stdout.strip() or "(no output)").splitlines()
        raise UserError(f"{what} failed: {msg[0]}" + (f" (+{len(msg) - 1} more lines)" if len(msg) > 1 else ""))
    if r.stderr.strip():
        # -Werror turns warnings into errors, but notes from other tools must not pass silently.
        raise UserError(f"{what} printed diagnostics: {r.stderr.strip().splitlines()[0]}")
    return r.stdout


def header_dir(header: Path, scratch: Path) -> Path:
    """A folder whose rod_gains.h is `header` (copied when it has another name)."""
    header = Path(header).resolve()
    if not header.is_file():
        raise UserError(f"header {header} not found")
    if header.name == "rod_gains.h":
        return header.parent
    d = scratch / "hdr"
    d.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(header, d / "rod_gains.h")
    return d


def core_sources() -> list[Path]:
    paths.require_firmware_sources()
    return sorted(paths.CORE_SRC.glob("*.c"))


def _sizes(files: list[Path]) -> dict[str, dict[str, int]]:
    out = _run([_need(SIZE), "-B", *map(str, files)], "arm-none-eabi-size")
    sizes = {}
    for line in out.splitlines()[1:]:
        parts = line.split()
        if len(parts) >= 6:
            sizes[Path(parts[5]).name] = {"text": int(parts[0]), "data": int(parts[1]), "bss": int(parts[2])}
    return sizes


def check_no_soft_double(objects: list[Path]) -> None:
    out = _run([_need(NM), "-u", *map(str, objects)], "arm-none-eabi-nm")
    bad, current = [], None
    for line in out.splitlines():
        if line.endswith(":") and not line.startswith(" "):
            current = Path(line[:-1]).name
        elif "__aeabi_d" in line or "__aeabi_f2d" in line:
            bad.append(f"{current}: {line.split()[-1]}")
    if bad:
        raise UserError("soft-double helpers referenced (a double reached the target code): " + ", ".join(bad))


def build(header: Path | None = None, out_dir: Path | None = None) -> TargetBuild:
    """Compile the core for the M4F against `header`; raise UserError on any warning or double."""
    header = Path(header or paths.COMMITTED_HEADER)
    cc = _need(CC)
    with tempfile.TemporaryDirectory(prefix="rod-target-") as tmp:
        scratch = Path(out_dir) if out_dir else Path(tmp)
        scratch.mkdir(parents=True, exist_ok=True)
        inc = [header_dir(header, scratch), paths.CORE_SRC]
        iflags = [f"-I{d}" for d in inc]
        objects = []
        for src in core_sources():
            obj = scratch / (src.stem + ".o")
            _run([cc, *TARGET_FLAGS, *iflags, "-c", str(src), "-o", str(obj)], f"compiling {src.name}")
            objects.append(obj)
        check_no_soft_double(objects)
        result = TargetBuild(header=header, objects=_sizes(objects))

        entry = scratch / "rod_target_entry.c"
        entry.write_text(_ENTRY_C)
        entry_obj = scratch / "rod_target_entry.o"
        _run([cc, *TARGET_FLAGS, *iflags, "-c", str(entry), "-o", str(entry_obj)], "compiling the size probe")
        elf = scratch / "rod_core.elf"
        keep = [f"-Wl,--undefined={name}" for name in (*BOARD_API, "rod_target_device")]
        _run([cc, "-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-nostartfiles",
              "--specs=nosys.specs", "-Wl,--gc-sections", "-Wl,--entry=rod_device_step", *keep,
              *map(str, objects), str(entry_obj), "-lm", "-o", str(elf)], "linking the core")
        check_no_soft_double([elf])
        result.linked = _sizes([elf])[elf.name]
        syms = _run([_need(NM), "-S", str(elf)], "arm-none-eabi-nm")
        for line in syms.splitlines():
            parts = line.split()
            if len(parts) == 4 and parts[3] == "rod_target_device":
                result.device_bytes = int(parts[1], 16)
        return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rodctl.build.target_build", description=__doc__.splitlines()[0])
    ap.add_argument("--header", type=Path, help="rod_gains.h to build against (default: the committed one)")
    ap.add_argument("--json", action="store_true", help="print the report as JSON")
    args = ap.parse_args(argv)
    try:
        r = build(args.header)
    except UserError as e:
        print(f"target build: {e}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(r.to_json(), indent=1))
        return 0
    print(f"core built for Cortex-M4F against {r.header}: no warnings, no soft-double helpers")
    for name, s in sorted(r.objects.items()):
        print(f"  {name:<20} text {s['text']:6d}  data {s['data']:4d}  bss {s['bss']:5d}")
    print(f"objects: flash {r.object_flash} B, RAM {r.object_ram} B")
    print(f"linked from the board API (--gc-sections): flash {r.flash_bytes} B, RAM {r.ram_bytes} B "
          f"(of which one rod_device_t: {r.device_bytes} B)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
