"""The core builds clean for the host and the Cortex-M4F, float only, and refuses a stale header."""

import re
import subprocess
from pathlib import Path

import pytest

from firmware_sil import header_path
from rodctl import paths
from host_tools import host_compiler, host_cxx, needs_tools, tool
from rodctl.build import target_build
from rodgains.errors import UserError

WARN = ["-std=c11", "-Wall", "-Wextra", "-Wdouble-promotion", "-Werror"]
ARM = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-O2", "-fsingle-precision-constant"]
SIL = paths.FIRMWARE / "sil"
needs_arm = needs_tools(target_build.CC, target_build.NM, target_build.SIZE)  # what target_build runs


@pytest.fixture(scope="module")
def host_cc() -> str:
    """The SIL build's compiler, resolved once: the host checks here hold for that build."""
    return host_compiler()


def compile_c(cc: str, source: Path, include: list[Path], extra=(), out: Path | None = None) -> subprocess.CompletedProcess:
    out = out or source.with_suffix(".o")
    cmd = [cc, *WARN, *extra, *[f"-I{d}" for d in include], "-c", str(source), "-o", str(out)]
    return subprocess.run(cmd, capture_output=True, text=True)


def headers() -> dict[str, Path]:
    return {"committed": paths.COMMITTED_HEADER, "n2": header_path(("rod.edges=2",)),
            "n20": header_path(("rod.edges=20",))}


@pytest.mark.parametrize("which", ["committed", "n2", "n20"])
def test_core_and_sil_compile_warning_free_on_the_host(which, host_cc, tmp_path):
    inc = [headers()[which].parent, paths.CORE_SRC, SIL]
    for src in [*sorted(paths.CORE_SRC.glob("*.c")), SIL / "rod_sil.c"]:
        r = compile_c(host_cc, src, inc, ["-O2"], tmp_path / (src.stem + ".o"))
        assert r.returncode == 0 and not r.stderr, f"{host_cc} {src.name}: {r.stderr}"


@needs_arm
@pytest.mark.parametrize("which", ["committed", "n20"])
def test_core_builds_for_the_m4f_without_soft_double(which):
    build = target_build.build(headers()[which])
    assert {"rod_observer.o", "rod_control.o", "rod_device.o", "rod_angle.o", "rod_motor.o"} <= set(build.objects)
    assert build.flash_bytes > 1000
    assert build.ram_bytes >= build.device_bytes > 0


@needs_arm
def test_soft_double_check_catches_a_double(tmp_path):
    src = tmp_path / "bad.c"
    src.write_text("double twice(double x) { return 2.0 * x; }\nfloat f(float x) { return (float)twice(x); }\n")
    r = subprocess.run([tool("arm-none-eabi-gcc"), "-std=c11", *ARM, "-c", str(src), "-o", str(tmp_path / "bad.o")],
                       capture_output=True, text=True)
    assert r.returncode == 0
    with pytest.raises(UserError, match="__aeabi_d"):
        target_build.check_no_soft_double([tmp_path / "bad.o"])


def stale_header(tmp_path: Path, edit) -> Path:
    text = paths.COMMITTED_HEADER.read_text()
    new = edit(text)
    assert new != text
    d = tmp_path / "hdr"
    d.mkdir()
    (d / "rod_gains.h").write_text(new)
    src = tmp_path / "uses_config.c"
    src.write_text('#include "rod_config.h"\nint rod_config_probe;\n')
    return d


@pytest.mark.parametrize("cc", ["host", "arm-none-eabi-gcc"])
def test_stale_schema_version_stops_the_build(cc, request, tmp_path):
    cc = request.getfixturevalue("host_cc") if cc == "host" else tool(cc)
    d = stale_header(tmp_path, lambda t: re.sub(r"(#define ROD_GAINS_SCHEMA_VERSION\s+)\d+", r"\g<1>999", t))
    r = compile_c(cc, tmp_path / "uses_config.c", [d, paths.CORE_SRC])
    assert r.returncode != 0
    assert "#error" in r.stderr and "ROD_GAINS_SCHEMA_VERSION" in r.stderr


def test_missing_macro_stops_the_build(host_cc, tmp_path):
    d = stale_header(tmp_path, lambda t: re.sub(r"#define ROD_SPEED_LIMIT_RAD_S.*\n", "", t))
    r = compile_c(host_cc, tmp_path / "uses_config.c", [d, paths.CORE_SRC])
    assert r.returncode != 0 and "lacks a macro" in r.stderr


@pytest.mark.parametrize("macro, value, message", [
    ("ROD_CATCH_ANGLE_RAD", "1.2f", "default catch angle outside the SET range"),
    ("ROD_CATCH_ANGLE_RAD", "0.01f", "default catch angle outside the SET range"),
    ("ROD_SWING_AMPLITUDE_NM", "0.5f", "default swing amplitude outside the SET range"),
    ("ROD_HEARTBEAT_TIMEOUT_S", "20.0f", "default heartbeat timeout outside the SET range"),
    ("ROD_DUTY_MAX", "1.5f", "duty ceiling must be in (0, 1]"),
])
def test_hand_edited_float_defaults_stop_the_cpp_build(tmp_path, macro, value, message):
    """C11 cannot compare floats at compile time; the board layer is C++ and can (rod_config.h)."""
    d = stale_header(tmp_path, lambda t: re.sub(rf"(#define {macro}\s+)\S+", rf"\g<1>{value}", t))
    src = tmp_path / "uses_config.cpp"
    src.write_text('#include "rod_config.h"\nint rod_config_probe;\n')
    r = subprocess.run([host_cxx(), "-std=gnu++14", f"-I{d}", f"-I{paths.CORE_SRC}", "-c", str(src), "-o",
                        str(tmp_path / "u.o")], capture_output=True, text=True)
    assert r.returncode != 0 and message in r.stderr


def test_rod_config_has_no_float_static_assert_in_c():
    """Comparing floats in _Static_assert is a GCC extension clang rejects (the fuzz build needs clang)."""
    text = _code_only((paths.CORE_SRC / "rod_config.h").read_text())
    c_part = re.sub(r"#ifdef __cplusplus.*?#endif", "", text, flags=re.S)
    for m in re.finditer(r"ROD_STATIC_ASSERT\((.*?),\s*\"", c_part, flags=re.S):
        assert not re.search(r"\d\.\d*f|_RAD|_NM|_S\b|_V\b|_OHM|_MAX\b", m.group(1)), m.group(1)


@pytest.mark.parametrize("which", ["committed", "n20"])
def test_core_and_sil_compile_with_clang(which, tmp_path):
    clang = tool("clang")
    inc = [headers()[which].parent, paths.CORE_SRC, SIL]
    for src in [*sorted(paths.CORE_SRC.glob("*.c")), SIL / "rod_sil.c"]:
        r = compile_c(clang, src, inc, ["-O2", "-pedantic"], tmp_path / (src.stem + ".o"))
        assert r.returncode == 0 and not r.stderr, f"{src.name}: {r.stderr}"


def test_current_header_compiles(host_cc, tmp_path):
    src = tmp_path / "uses_config.c"
    src.write_text('#include "rod_config.h"\nint rod_config_probe;\n')
    r = compile_c(host_cc, src, [paths.COMMITTED_HEADER.parent, paths.CORE_SRC])
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("cxx", ["host", "arm-none-eabi-g++"])
def test_board_facing_headers_compile_as_cpp(cxx, tmp_path):
    """The Teensy sketch is C++: rod_device.h must work there (extern "C", static_assert)."""
    extra = ARM if cxx.startswith("arm") else []
    cxx = host_cxx() if cxx == "host" else tool(cxx)
    src = tmp_path / "board.cpp"
    src.write_text('#include "rod_device.h"\nstatic rod_device_t dev;\n'
                   'void tick(const rod_inputs_t *in, rod_outputs_t *out) { rod_device_step(&dev, in, out); }\n')
    r = subprocess.run([cxx, "-std=gnu++14", "-Wall", "-Wextra", "-Wdouble-promotion", "-Werror", *extra,
                        f"-I{paths.COMMITTED_HEADER.parent}", f"-I{paths.CORE_SRC}", "-c", str(src),
                        "-o", str(tmp_path / "board.o")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def _code_only(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    text = re.sub(r"//[^\n]*", " ", text)
    return re.sub(r'"(\\.|[^"\\])*"', '""', text)


def test_core_is_portable_float_only_c():
    for f in sorted(paths.CORE_SRC.glob("*.[ch]")):
        code = _code_only(f.read_text())
        assert "Arduino.h" not in f.read_text(), f.name
        assert not re.search(r"\bdouble\b", code), f"{f.name} uses double"
        assert not re.search(r"\b(malloc|calloc|realloc|free)\s*\(", code), f"{f.name} allocates"
        # every floating literal carries an f suffix
        bare = [m.group(0) for m in re.finditer(r"(?<![\w.])(\d+\.\d*|\.\d+|\d+(?=[eE]))([eE][+-]?\d+)?(?![\w.])", code)]
        assert not bare, f"{f.name}: unsuffixed float literals {bare[:5]}"
