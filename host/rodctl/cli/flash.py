"""rodctl build / rodctl flash: regenerate the gains header when the parameters changed, then PlatformIO.

    rodctl build [--env teensy35] [--params F] [--set S.K=V]      pio run -e teensy35
    rodctl flash [--env teensy35] [--port P | --upload-port P]    pio run -e teensy35 -t upload

Before anything is written or built: PlatformIO must be there (`pio`, `platformio`, or
`python3 -m platformio`), platformio.ini must define the environment, the platform must be
installed or the PlatformIO registry reachable, and for flash a Teensy must be on USB. Each
missing piece is one line and a non-zero exit. PlatformIO's whole output goes to
build/pio-<env>.log (or to the terminal with --verbose); a failure is summarized in one line.
"""

from __future__ import annotations

import argparse
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

from rodgains.errors import InputError, UserError

from rodctl import paths
from rodctl.link.session import is_tty

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


def ensure_header(args) -> None:
    """Regenerate firmware/include/rod_gains.h (+ .toml) when the parameters changed."""
    from rodctl.cli.gains import generated_files

    ns = argparse.Namespace(params=args.params, overrides=args.overrides, header=None)
    print("checking the gains header against the parameters (designing) ...", file=sys.stderr, flush=True)
    t = time.monotonic()
    d, files = generated_files(ns)
    stale = [f for f, text in files.items() if not f.exists() or f.read_text() != text]
    if stale:
        for f in stale:
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_text(files[f])
        shown = ", ".join(str(Path(f).relative_to(paths.REPO)) if paths.REPO in Path(f).parents else str(f)
                          for f in stale)
        print(f"parameters changed: regenerated {shown} (N={d.N}, {1 / d.dt:g} Hz) in {time.monotonic() - t:.1f} s",
              file=sys.stderr, flush=True)
    else:
        print(f"gains header up to date (N={d.N}, {1 / d.dt:g} Hz)", file=sys.stderr, flush=True)


def run_pio(cmd: list[str], project: Path, env: str, what: str, platform: str, verbose: bool) -> None:
    log = paths.BUILD / f"pio-{env}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    shown = " ".join(Path(c).name if i == 0 else c for i, c in enumerate(cmd))
    print(f"{what}: {shown}", file=sys.stderr, flush=True)
    if verbose:
        r = subprocess.run(cmd, cwd=project)
        if r.returncode != 0:
            raise UserError(f"{what} failed (exit {r.returncode}); PlatformIO's output is above")
        return
    tty = is_tty(sys.stderr)
    t0 = time.monotonic()
    last_line = ""
    tail: list[str] = []
    try:
        proc = subprocess.Popen(cmd, cwd=project, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                errors="replace", bufsize=1)
    except OSError as e:
        raise UserError(f"cannot run PlatformIO ({cmd[0]}): {e.strerror or e}") from None
    next_plain = t0 + 10
    with open(log, "w") as f:
        try:
            for line in proc.stdout:
                f.write(line)
                tail.append(line)
                s = line.strip()
                if s:
                    last_line = s
                now = time.monotonic()
                if tty:
                    sys.stderr.write(f"\r\x1b[K  {now - t0:5.0f} s  {last_line[:100]}")
                    sys.stderr.flush()
                elif now >= next_plain:
                    print(f"  {now - t0:5.0f} s  {last_line[:100]}", file=sys.stderr, flush=True)
                    next_plain = now + 10
            proc.wait()
        except KeyboardInterrupt:
            proc.terminate()
            proc.wait()
            raise
        finally:
            if tty:
                sys.stderr.write("\r\x1b[K")
                sys.stderr.flush()
    if proc.returncode != 0:
        line = summarize_failure("".join(tail), platform)
        raise UserError(f"{what} failed: {line} (full output: {log})")
    print(f"{what}: done in {time.monotonic() - t0:.0f} s (output in {log})", file=sys.stderr, flush=True)


def run(args, upload: bool) -> int:
    from rodgains.params import load_params

    what = "flash" if upload else "build"
    if not args.project_dir:
        paths.require_checkout(f"rodctl {what}")
    load_params(args.params, args.overrides)  # the user's inputs first: a bad file is named, exit 2
    project = Path(args.project_dir) if args.project_dir else paths.REPO
    platform = env_platform(project, args.env)
    pio = find_platformio()
    name = platform_name(platform)
    if not platform_installed(name) and not registry_reachable():
        raise UserError(f"PlatformIO could not install platform {name} (no internet?): it is not in "
                        f"{platforms_dir()} and {REGISTRY_HOST} cannot be reached; install it once on a "
                        f"connected machine with `pio pkg install -g -p {name}`")
    upload_port = None
    if upload:
        from rodctl.link.ports import find_port

        upload_port = args.upload_port or args.port
        if upload_port is None and not args.no_port_check:
            find_port(None)  # one clear line when no (or more than one) Teensy is on USB
    ensure_header(args)
    cmd = [*pio, "run", "-e", args.env]
    if upload:
        cmd += ["-t", "upload"]
        if upload_port:
            cmd += ["--upload-port", upload_port]
    run_pio(cmd, project, args.env, what, name, args.verbose)
    if upload:
        print("flashed: the board restarts DISARMED; check it with `rodctl status`")
    return 0


def register(sub) -> None:
    for name, upload in (("build", False), ("flash", True)):
        desc = ("Regenerate firmware/include/rod_gains.h when the parameters changed, then "
                + ("build and upload the firmware with PlatformIO (pio run -e ENV -t upload)." if upload
                   else "build the firmware with PlatformIO (pio run -e ENV) without uploading."))
        p = sub.add_parser(name, help=("build and upload the firmware (PlatformIO)" if upload
                                       else "build the firmware without uploading (PlatformIO)"),
                           description=desc)
        p.add_argument("--env", default="teensy35", help="PlatformIO environment (default teensy35)")
        p.add_argument("--params", metavar="FILE", help="parameter file (TOML); default: gains/rodgains/default.toml")
        p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[], dest="overrides",
                       help="override one parameter (repeatable)")
        p.add_argument("--project-dir", metavar="DIR", help="PlatformIO project (default: the repository root)")
        p.add_argument("--verbose", "-v", action="store_true", help="show PlatformIO's output as it runs")
        if upload:
            p.add_argument("--port", metavar="PORT", help="the board's serial port (default: the one Teensy on USB)")
            p.add_argument("--upload-port", metavar="PORT", help="passed to PlatformIO as --upload-port")
            p.add_argument("--no-port-check", action="store_true",
                           help="upload even when no Teensy serial port is seen (e.g. a board in its bootloader)")
        p.set_defaults(func=lambda a, up=upload: run(a, up))
