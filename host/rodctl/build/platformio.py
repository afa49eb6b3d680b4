"""The firmware's PlatformIO build: finding PlatformIO, the environment's platform, running `pio run`.

    pio = find_platformio()                                  # ["/usr/bin/pio"] or [python, -m, platformio]
    name = platform_name(env_platform(REPO, "teensy35"))     # "teensy"
    platform_installed(name) or registry_reachable()         # can `pio run` get its platform?
    run_pio([*pio, "run", "-e", "teensy35"], REPO, pio_log("teensy35"), "build", name, verbose=False)

PlatformIO's whole output goes to build/pio-<env>.log (or to the terminal when verbose); a failure
is summarized in one line. Nothing here prints: progress goes to the caller's callbacks.
"""

from __future__ import annotations

import configparser
import importlib.util
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Callable

from rodgains.errors import InputError, UserError

from rodctl import paths

REGISTRY_HOST = "api.registry.platformio.org"
_NET_ERRORS = ("HTTPClientError", "InternetConnectionError", "ConnectionError", "Could not resolve",
               "Name or service not known", "Max retries exceeded", "Temporary failure in name resolution")


def module_available(name: str) -> bool:
    return importlib.util.find_spec(name) is not None


def find_platformio() -> list[str]:
    """The command that runs PlatformIO; UserError when it is not installed."""
    for name in ("pio", "platformio"):
        path = shutil.which(name)
        if path:
            return [path]
    if module_available("platformio"):
        return [sys.executable, "-m", "platformio"]
    raise UserError("PlatformIO not found (no `pio` or `platformio` on PATH, no `python3 -m platformio`): "
                    "install it with `pip install platformio` (or `pip install -e '.[flash]'`)")


def env_platform(project: Path, env: str) -> str:
    """The platform of [env:ENV] in PROJECT/platformio.ini."""
    ini = project / "platformio.ini"
    if not ini.is_file():
        raise InputError(f"--project-dir {project}: no platformio.ini there: the firmware's PlatformIO project is "
                         "not there")
    cp = configparser.ConfigParser(interpolation=None, strict=False)
    try:
        cp.read(ini)
    except configparser.Error as e:
        raise UserError(f"{ini}: cannot parse ({str(e).splitlines()[0]})") from None
    sec = f"env:{env}"
    if not cp.has_section(sec):
        envs = [s[4:] for s in cp.sections() if s.startswith("env:")]
        raise InputError(f"--env {env}: {ini} has no [env:{env}] (environments: {', '.join(envs) or 'none'})")
    platform = cp.get(sec, "platform", fallback=None) or cp.get("env", "platform", fallback=None)
    if not platform:
        raise UserError(f"{ini}: [env:{env}] names no platform")
    return platform.strip()


def platform_name(spec: str) -> str:
    """'teensy', 'platformio/teensy@^5', 'https://.../platform-teensy.git' -> 'teensy'."""
    s = spec.split("@")[0].strip().rstrip("/")
    s = s.rsplit("/", 1)[-1]
    s = re.sub(r"\.git$", "", s)
    return re.sub(r"^platform-", "", s)


def platforms_dir() -> Path:
    core = Path(os.environ.get("PLATFORMIO_CORE_DIR") or Path.home() / ".platformio")
    return Path(os.environ.get("PLATFORMIO_PLATFORMS_DIR") or core / "platforms")


def platform_installed(name: str) -> bool:
    d = platforms_dir()
    if not d.is_dir():
        return False
    return any(p.is_dir() and (p.name == name or p.name.startswith(name + "@")) for p in d.iterdir())


def registry_reachable(timeout: float = 3.0, host: str = REGISTRY_HOST, port: int = 443) -> bool:
    """Can PlatformIO reach its registry? (True behind a proxy: we cannot tell from here.)"""
    if any(os.environ.get(k) for k in ("HTTPS_PROXY", "https_proxy", "HTTP_PROXY", "http_proxy", "ALL_PROXY")):
        return True
    result = []

    def probe():
        try:
            socket.create_connection((host, port), timeout=timeout).close()
            result.append(True)
        except OSError:
            result.append(False)

    t = threading.Thread(target=probe, daemon=True)
    t.start()
    t.join(timeout + 0.5)
    return bool(result and result[0])


def summarize_failure(output: str, platform: str) -> str:
    """One line for a failed pio run."""
    lines = [ln.strip() for ln in output.splitlines() if ln.strip()]
    installing = [ln for ln in lines if "Installing" in ln or "Platform Manager" in ln or "Tool Manager" in ln]
    if installing and any(any(k in ln for k in _NET_ERRORS) for ln in lines):
        last = installing[-1]
        kind = "tool" if "Tool Manager" in last else "package" if "Package Manager" in last else "platform"
        what = last.split("Installing", 1)[-1].strip() if "Installing" in last else platform
        return f"PlatformIO could not install {kind} {what or platform} (no internet?)"
    for ln in lines:
        if ln.startswith("Error:") or "UnknownBoard" in ln or "UnknownPlatform" in ln or "NotPlatformIOProject" in ln:
            return ln
    for ln in lines:
        if re.search(r"\berror:", ln) or ln.startswith("*** ["):
            return ln
    for ln in lines:
        if any(k in ln for k in _NET_ERRORS):
            return f"PlatformIO could not reach the internet: {ln}"
    return lines[-1] if lines else "no output"


def pio_log(env: str) -> Path:
    """build/pio-<env>.log, its folder created."""
    log = paths.BUILD / f"pio-{env}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    return log


def run_pio(cmd: list[str], project: Path, log: Path, what: str, platform: str, verbose: bool,
            on_line: Callable[[float, str], None] = lambda seconds, last_line: None,
            on_end: Callable[[], None] = lambda: None) -> float:
    """Run PlatformIO's `cmd` in `project`; returns the seconds it took; UserError when it fails.

    Verbose: its output goes to the terminal. Otherwise it goes to `log`, on_line(seconds since
    start, last non-empty line) follows each line, and on_end() follows the last (also on Ctrl-C).
    """
    t0 = time.monotonic()
    if verbose:
        r = subprocess.run(cmd, cwd=project)
        if r.returncode != 0:
            raise UserError(f"{what} failed (exit {r.returncode}); PlatformIO's output is above")
        return time.monotonic() - t0
    last_line = ""
    tail: list[str] = []
    try:
        proc = subprocess.Popen(cmd, cwd=project, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                errors="replace", bufsize=1)
    except OSError as e:
        raise UserError(f"cannot run PlatformIO ({cmd[0]}): {e.strerror or e}") from None
    with open(log, "w") as f:
        try:
            for line in proc.stdout:
                f.write(line)
                tail.append(line)
                s = line.strip()
                if s:
                    last_line = s
                on_line(time.monotonic() - t0, last_line)
            proc.wait()
        except KeyboardInterrupt:
            proc.terminate()
            proc.wait()
            raise
        finally:
            on_end()
    if proc.returncode != 0:
        line = summarize_failure("".join(tail), platform)
        raise UserError(f"{what} failed: {line} (full output: {log})")
    return time.monotonic() - t0
