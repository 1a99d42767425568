"""Real ``arcf-service`` and ``arcf-router`` processes on free loopback ports: the one way the
load tools, the benchmarks and the integration tests start them.

Each runs the installed program (``python -m arcf.service.app`` of this interpreter, from any
working directory), waits for its "ready" line and stops it with SIGTERM (:func:`terminate`,
which the adapters' tests and benchmarks use for the processes they start themselves).
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from arcf.service.scrape import scrape


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def terminate(proc: subprocess.Popen[Any], timeout: float = 30.0) -> int:
    """Stop a program as its operator would: SIGTERM (unless it has exited), then its exit
    code (a clean shutdown is 0); SIGKILL (and SIGCONT, for a frozen one) if it has not exited
    within ``timeout``. Its pipes are closed after. One way for every process the tools and
    tests start, so that a stuck one is ended the same way everywhere."""
    try:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            return proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.send_signal(signal.SIGCONT)
            return proc.wait(timeout=10)
    finally:
        for pipe in (proc.stdin, proc.stdout, proc.stderr):
            if pipe is not None:
                pipe.close()


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


class Program:
    """A console program of this package started as ``python -m <module>``, ready when its
    first stdout line says so (within ``start_s``; else it is killed)."""

    def __init__(self, module: str, args: list[str], *, quiet: bool,
                 env: Mapping[str, str] | None, start_s: float = 180.0,
                 prefix: Sequence[str] = ()) -> None:
        # the log goes to a file, not a pipe: nobody reads a pipe during a long run, and a
        # full pipe would block the program's logging threads (and with them the program)
        self._log = tempfile.TemporaryFile(mode="w+") if quiet else None  # noqa: SIM115
        # ``prefix``: e.g. ``ip netns exec <ns>``, which execs the program (same pid)
        self.proc = subprocess.Popen([*prefix, sys.executable, "-m", module, *args],
                                     stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     env={**os.environ, **(env or {})})
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], start_s)
        self.ready_line = self.proc.stdout.readline().strip() if ready else ""
        if "ready" not in self.ready_line:
            try:  # it exits by itself when it knows why it cannot start
                code = self.proc.wait(timeout=10 if ready else 0.1)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                code = self.proc.wait(timeout=10)
            log = self.log()
            self.proc.stdout.close()
            if self._log is not None:
                self._log.close()
            said = self.ready_line or f"no ready line within {start_s:g} s"
            raise RuntimeError(f"{module} did not start (exit code {code}): {said!r} {log}")

    @property
    def pid(self) -> int:
        return self.proc.pid

    def log(self) -> str:
        """What the program wrote to stderr so far (empty unless ``quiet``)."""
        if self._log is None:
            return ""
        self._log.flush()
        self._log.seek(0)
        return self._log.read()

    def stop(self, timeout: float = 30.0) -> int:
        """SIGTERM, then its exit code (a clean shutdown is 0); SIGKILL (and SIGCONT, for a
        frozen one) if it has not exited within ``timeout``."""
        code = terminate(self.proc, timeout)
        if self._log is not None:
            self._log.close()
            self._log = None
        return code

    def __enter__(self) -> Program:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class ServiceProcess(Program):
    """One ``arcf-service``: by default with its embedded router listening on ``listen`` (a free
    loopback port unless given); with ``connect``, a client-mode instance of a multi-instance
    deployment. Metrics on a free port unless ``metrics`` is False."""

    def __init__(self, *extra: str, connect: str | None = None, listen: str | None = None,
                 workers: int = 2, metrics: bool = True, quiet: bool = True,
                 env: Mapping[str, str] | None = None, prefix: Sequence[str] = (),
                 metrics_host: str = "127.0.0.1") -> None:
        if connect:
            self.endpoint = connect
            where = ["--mode", "client", "--connect", connect]
        else:
            self.endpoint = listen or f"tcp/127.0.0.1:{free_port()}"
            where = ["--listen", self.endpoint]
        metrics_port = free_port() if metrics else -1
        self.metrics_url = (f"http://{metrics_host}:{metrics_port}/metrics" if metrics
                            else None)
        super().__init__("arcf.service.app",
                         [*where, "--workers", str(workers), "--metrics-host", metrics_host,
                          "--metrics-port", str(metrics_port), *extra],
                         quiet=quiet, env=env, prefix=prefix)
        self.workers = worker_pids(self.proc.pid)

    def kill(self, timeout: float = 60.0) -> None:
        """SIGKILL the instance's main process, as a crash would, and wait until it and its
        workers (which notice their parent is gone) have exited."""
        from .waiting import wait_until

        workers = worker_pids(self.pid)
        self.proc.kill()
        self.proc.wait(timeout=timeout)
        wait_until(lambda: not any(Path(f"/proc/{p}").exists() for p in workers),
                   timeout=timeout, what="the killed instance's workers gone")
        self.stop()

    def metric(self, name: str) -> float:
        """Sum of every series of a metric (all label values), scraped over HTTP."""
        return scrape(self.metrics_url).get(name, 0.0)

    def __enter__(self) -> ServiceProcess:
        return self


class RouterProcess(Program):
    """A plain Zenoh router (``arcf-router``) on ``endpoint`` (a free loopback port unless
    given), joined to the routers at ``connect`` (a mesh: each router connects to the others)."""

    def __init__(self, endpoint: str | None = None, connect: Sequence[str] = (), *,
                 metrics: bool = False, quiet: bool = True, prefix: Sequence[str] = (),
                 metrics_host: str = "127.0.0.1", lease_ms: int | None = None) -> None:
        self.endpoint = endpoint or f"tcp/127.0.0.1:{free_port()}"
        peers = [arg for e in connect for arg in ("--connect", e)]
        port = free_port() if metrics else -1
        #: its Prometheus endpoint (``metrics``), else None
        self.metrics_url = f"http://{metrics_host}:{port}/metrics" if metrics else None
        super().__init__("arcf.service.router",
                         ["--listen", self.endpoint, *peers, "--metrics-host", metrics_host,
                          "--metrics-port", str(port),
                          *(["--lease-ms", str(lease_ms)] if lease_ms else [])],
                         quiet=quiet, env=None, prefix=prefix)

    def __enter__(self) -> RouterProcess:
        return self


def start_instances(ids: Sequence[str], router: str, *extra: str, workers: int = 1,
                    quiet: bool = True) -> dict[str, ServiceProcess]:
    """Service instances ``ids`` (client mode, joined through the router at ``router``),
    started side by side; if one fails to start, the others are stopped and the error raised."""
    def start(instance: str) -> ServiceProcess:
        return ServiceProcess("--instance-id", instance, *extra, connect=router,
                              workers=workers, quiet=quiet)

    with ThreadPoolExecutor(max(len(ids), 1)) as pool:
        futures = {i: pool.submit(start, i) for i in ids}
    started = {i: f.result() for i, f in futures.items() if f.exception() is None}
    failed = [f.exception() for f in futures.values() if f.exception() is not None]
    if failed:
        for svc in started.values():
            svc.stop()
        raise failed[0]  # type: ignore[misc]
    return started
