"""Command-line helpers shared by the scripts in ``experiments/``.

- :class:`HelpFormatter`: keeps the module docstring's layout and appends every option's default
  (``(default: …)``) unless the default is ``None`` (the option's help then says what that means);
- :func:`start_viewer`: starts a Rerun viewer (native, or a web viewer served over HTTP) that a run
  streams to while it goes (``record.live_url``).
"""

from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

#: gRPC port the Rerun viewer listens on for SDKs (Rerun's default).
VIEWER_GRPC_PORT = 9876
#: HTTP port of the served web viewer (Rerun's default).
WEB_VIEWER_PORT = 9090


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """The description as written, and ``(default: X)`` after every option's help whose default
    is not ``None`` or already named in the help text."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (
            "%(default)" in text
            or "(default" in text
            or action.default is None
            or action.default is argparse.SUPPRESS
            or not action.option_strings
            or isinstance(action, (argparse._HelpAction, argparse._VersionAction))
            or (isinstance(action, argparse._StoreTrueAction) and action.default is False)
        ):
            return text
        default = action.default
        if isinstance(default, (list, tuple)):
            shown = " ".join(_shown(v) for v in default) or "none"
        else:
            shown = _shown(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


def _shown(value: object) -> str:
    """A default as the user would type it: paths inside the repository relative to it."""
    from .config import REPO_ROOT

    text = str(value)
    root = str(REPO_ROOT) + "/"
    return text.removeprefix(root)


def rerun_executable() -> str:
    """The ``rerun`` CLI of this Python environment (the pinned rerun-sdk), else the one on PATH."""
    beside = Path(sys.executable).with_name("rerun")
    if beside.exists():
        return str(beside)
    found = shutil.which("rerun")
    if found is None:
        raise FileNotFoundError("no `rerun` executable: install rerun-sdk (make setup)")
    return found


def has_display() -> bool:
    """Whether a native (windowed) viewer can open here."""
    import os

    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform == "darwin"


def _listening(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def web_viewer_url(grpc_port: int = VIEWER_GRPC_PORT, web_port: int = WEB_VIEWER_PORT) -> str:
    """The address to open in a browser for a web viewer served by ``rerun --serve-web``."""
    return f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"


def start_viewer(web: bool, *, wait_s: float = 15.0) -> str:
    """Start a viewer that a recording can stream to and return its gRPC proxy URL (for
    ``record.live_url``). ``web``: ``rerun --serve-web`` (no display needed; prints the address to
    open); else a native viewer window. A viewer already listening on the port is reused. The
    viewer is a separate process that outlives the run."""
    url = f"rerun+http://127.0.0.1:{VIEWER_GRPC_PORT}/proxy"
    if _listening(VIEWER_GRPC_PORT):
        print(f"streaming to the viewer already listening on port {VIEWER_GRPC_PORT}", file=sys.stderr)
        return url
    cmd = [rerun_executable(), "--port", str(VIEWER_GRPC_PORT)]
    cmd += ["--serve-web", "--web-viewer-port", str(WEB_VIEWER_PORT)] if web else ["--expect-data-soon"]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, start_new_session=True
    )
    deadline = time.monotonic() + wait_s
    while not _listening(VIEWER_GRPC_PORT):
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the viewer did not start: {' '.join(cmd)} (exit status {proc.poll()})")
        time.sleep(0.2)
    if web:
        print(
            f"web viewer (pid {proc.pid}, stop it with `kill {proc.pid}`): open {web_viewer_url()}\n"
            f"  from another machine: ssh -L {WEB_VIEWER_PORT}:localhost:{WEB_VIEWER_PORT} "
            f"-L {VIEWER_GRPC_PORT}:localhost:{VIEWER_GRPC_PORT} <this host>, then open the same address",
            file=sys.stderr,
        )
    return url
