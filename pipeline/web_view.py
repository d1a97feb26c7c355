"""Rerun's web viewer, served from this machine: watch a run (or a replay) from a browser.

A headless CCTV box has no display, so ``--rerun web`` starts rerun's own server as a child
process, ``rerun --serve-web --bind ADDR --port GRPC --web-viewer-port WEB``: it hosts the
viewer page (HTML + Wasm) on WEB and a gRPC proxy on GRPC that keeps the recent data
(``web.memory_limit``) for browsers that connect late. The run streams its recording to the
proxy; a browser opens ``http://ADDR:WEB/?url=rerun+http://ADDR:GRPC/proxy``.

Loopback by default: set ``web.bind = "0.0.0.0"`` to let other machines watch (rerun's server
has no authentication; use an SSH tunnel or a trusted network). The Python SDK's
``rr.serve_web_viewer`` cannot choose its bind address, hence the child process.
"""

from __future__ import annotations

import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

from core.config import WebConfig
from core.errors import ConfigError, HeightpipeError
from stages.rerun_sink import web_grpc_url



@dataclass(frozen=True)
class WebViewConstants:
    """The web view's fixed numbers (the rule is in docs/design.md, Configuration)."""

    start_timeout_s: float = 20.0
    """How long the viewer server may take to open its ports before the run gives up: a cold
    start of the ``rerun`` binary on a loaded box takes seconds."""


CONSTANTS = WebViewConstants()


def _rerun_executable() -> str:
    """The rerun binary of the installed rerun-sdk.

    Not the ``rerun`` script on PATH: that is a Python wrapper that starts the binary as its own
    child, so stopping the wrapper would leave the server running.
    """
    try:
        import rerun_cli

        binary = Path(rerun_cli.__file__).with_name("rerun")
        if binary.is_file():
            return str(binary)
    except ImportError:
        pass
    found = shutil.which("rerun")
    if found is None:
        raise HeightpipeError("the rerun command (from rerun-sdk) was not found: cannot serve the web viewer")
    return found


def _die_with_parent() -> None:
    """In the child: SIGTERM when heightpipe dies, even by kill -9 (Linux; elsewhere a no-op)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        except OSError:
            pass


def check_port_free(bind: str, port: int, key: str) -> None:
    """One clear line when another program (an earlier run?) already listens there."""
    family = socket.AF_INET6 if ":" in bind else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        try:
            probe.bind((bind, port))
        except OSError as exc:
            raise HeightpipeError(
                f"cannot serve the web viewer: {bind}:{port} ({key}) is taken or unavailable "
                f"({exc.strerror}); stop what uses it or choose another with --set {key}=PORT") from None


def _listening(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.settimeout(0.5)
        return probe.connect_ex((host, port)) == 0


class WebViewer:
    """The child rerun server; ``stop()`` (or leaving the ``with`` block) ends it."""

    def __init__(self, config: WebConfig):
        if not (0 < config.web_port < 65536 and 0 < config.grpc_port < 65536):
            raise ConfigError("web.web_port and web.grpc_port must be 1..65535")
        if config.web_port == config.grpc_port:
            raise ConfigError("web.web_port and web.grpc_port must differ")
        self.config = config
        check_port_free(config.bind, config.web_port, "web.web_port")
        check_port_free(config.bind, config.grpc_port, "web.grpc_port")
        self.grpc_url = web_grpc_url(config.bind, config.grpc_port)
        command = [_rerun_executable(), "--serve-web", "--bind", config.bind,
                   "--port", str(config.grpc_port), "--web-viewer-port", str(config.web_port),
                   "--server-memory-limit", config.memory_limit]
        self._log = tempfile.TemporaryFile("w+")  # not a pipe: a full pipe would stall the server
        self._process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                         stderr=self._log, text=True, preexec_fn=_die_with_parent)
        self._wait_until_listening()

    @property
    def host(self) -> str:
        bind = self.config.bind
        return socket.gethostname() if bind in ("0.0.0.0", "::") else bind

    @property
    def page_url(self) -> str:
        """The address to open in a browser (the proxy's address as the browser must reach it)."""
        proxy = f"rerun+http://{self.host}:{self.config.grpc_port}/proxy"
        return f"http://{self.host}:{self.config.web_port}/?url={urllib.parse.quote(proxy, safe='')}"

    def _wait_until_listening(self) -> None:
        local = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(self.config.bind, self.config.bind)
        deadline = time.monotonic() + CONSTANTS.start_timeout_s
        while time.monotonic() < deadline:
            if self._process.poll() is not None:
                self._log.seek(0)
                last = [line for line in self._log.read().splitlines() if line.strip()]
                raise HeightpipeError("the rerun web viewer server exited at start: "
                                      + (last[-1] if last else f"exit code {self._process.returncode}"))
            if _listening(local, self.config.web_port) and _listening(local, self.config.grpc_port):
                return
            time.sleep(0.1)
        self.stop()
        raise HeightpipeError(f"the rerun web viewer server did not start within {CONSTANTS.start_timeout_s:.0f} s")

    def wait_for_ctrl_c(self) -> None:
        """Keeps serving (the finished recording stays viewable) until Ctrl-C or SIGTERM.

        The "Ctrl-C to stop" line is printed inside the guarded block: a Ctrl-C that comes as
        soon as it is read must end the wait, not the run with "interrupted".
        """
        def stop_waiting(_signum, _frame):
            raise KeyboardInterrupt

        previous = signal.signal(signal.SIGTERM, stop_waiting)
        try:
            print(f"heightpipe: still serving the web viewer at {self.page_url} - Ctrl-C to stop",
                  file=sys.stderr, flush=True)
            while self._process.poll() is None:
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
        finally:
            signal.signal(signal.SIGTERM, previous)

    def stop(self) -> None:
        if self._process.poll() is None:
            self._process.terminate()
            try:
                self._process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        self._log.close()

    def __enter__(self) -> WebViewer:
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop()
