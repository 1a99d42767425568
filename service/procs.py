"""Real ``arcf-service`` and ``arcf-router`` processes on loopback free ports.

For the integration tests, the benchmarks and ``arcf-loadtest --spawn-service``: each starts
the real program as a subprocess, waits for its "ready" line and stops it with SIGTERM.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from .scrape import scrape


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def worker_pids(pid: int) -> set[int]:
    """Worker processes of the service: spawned children (not multiprocessing's tracker)."""
    out: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            out |= {int(p) for p in (task / "children").read_text().split()}
    workers = set()
    for child in out:
        with contextlib.suppress(OSError):
            if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes():
                workers.add(child)
    return workers


class ServiceProcess:
    """One ``arcf-service``: by default with its embedded router on a free port; with
    ``connect``, a client-mode instance of a multi-instance deployment."""

    def __init__(self, *extra: str, connect: str | None = None, workers: int = 2,
                 quiet: bool = True) -> None:
        if connect:
            self.endpoint = connect
            where = ["--mode", "client", "--connect", connect]
        else:
            self.endpoint = f"tcp/127.0.0.1:{free_port()}"
            where = ["--listen", self.endpoint]
        metrics_port = free_port()
        self.metrics_url = f"http://127.0.0.1:{metrics_port}/metrics"
        # the log goes to a file, not a pipe: nobody reads a pipe during a long run, and a
        # full pipe would block the service's logging threads (and with them the service)
        self._log = tempfile.TemporaryFile(mode="w+") if quiet else None  # noqa: SIM115
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service.app", *where, "--workers", str(workers),
             "--metrics-port", str(metrics_port), *extra],
            stdout=subprocess.PIPE, stderr=self._log, text=True,
            cwd=Path(__file__).resolve().parent.parent, env=dict(os.environ))
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if "ready" not in line:
            self.proc.kill()
            self.proc.wait(timeout=10)
            raise RuntimeError(f"service did not start: {line!r} {self.log()}")
        self.workers = worker_pids(self.proc.pid)

    def log(self) -> str:
        """What the service wrote to stderr so far (empty unless ``quiet``)."""
        if self._log is None:
            return ""
        self._log.flush()
        self._log.seek(0)
        return self._log.read()

    def metric(self, name: str) -> float:
        """Sum of every series of a metric (all label values), scraped over HTTP."""
        return scrape(self.metrics_url).get(name, 0.0)

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(timeout=30)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        if self._log is not None:
            self._log.close()
            self._log = None
        return code




class RouterProcess:
    """A plain Zenoh router (``arcf-router``) on a free loopback port."""

    def __init__(self) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service.router", "--listen", self.endpoint],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            cwd=Path(__file__).resolve().parent.parent)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if "ready" not in line:
            self.proc.kill()
            raise RuntimeError(f"router did not start: {line!r}")

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout=30)
