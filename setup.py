"""Build step only (the project is described in pyproject.toml).

A wheel must run `rodctl sim`, `gains` and the protocol tools without a clone, so build_py copies
what they read from firmware/ into the package as rodctl/_firmware/ (rodctl.paths falls back to
it when it is not inside a clone). The PlatformIO project and the board layer stay out: building
and flashing the Teensy need the clone.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
# (folder under firmware/, file patterns) that the installed package carries
PACKAGED_FIRMWARE = [
    ("protocol", ("rodlink.toml",)),
    ("src/core", ("*.c", "*.h")),
    ("sil", ("*.c", "*.h")),
    ("include", ("rod_gains.h", "rod_gains.toml")),
]


class BuildPyWithFirmware(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):  # an editable install reads the clone itself
            return
        dest_root = Path(self.build_lib) / "rodctl" / "_firmware"
        for folder, patterns in PACKAGED_FIRMWARE:
            src = HERE / "firmware" / folder
            files = sorted({f for pat in patterns for f in src.glob(pat)})
            if not files:
                raise SystemExit(f"setup.py: nothing matches {patterns} in {src}")
            (dest_root / folder).mkdir(parents=True, exist_ok=True)
            for f in files:
                shutil.copyfile(f, dest_root / folder / f.name)


setup(cmdclass={"build_py": BuildPyWithFirmware})
