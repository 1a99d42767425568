"""What the adapters' tests share."""

from __future__ import annotations

import subprocess
import threading
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import pytest


class _Watch:
    def close(self) -> None:
        pass

    def undeclare(self) -> None:
        pass


class _Session:
    """The Zenoh session's part the stream taps use: a subscriber on the video key."""

    def __init__(self, callbacks: dict[str, Any]) -> None:
        self.callbacks = callbacks

    def declare_subscriber(self, key: str, callback: Any) -> _Watch:
        self.callbacks["video"] = callback
        return _Watch()


class OfflineClient:
    """What the endpoint asks of a service client before any command: its result and frame
    callbacks, kept to be called by the test."""

    def __init__(self) -> None:
        self.callbacks: dict[str, Any] = {}
        self.session = _Session(self.callbacks)

    def frames(self, stream_id: str, callback: Any) -> _Watch:
        self.callbacks["frames"] = callback
        return _Watch()

    def results(self, stream_id: str, callback: Any) -> _Watch:
        self.callbacks["results"] = callback
        return _Watch()

    def start(self, stream_id: str, box: Any, preset: str = "arcf-hc", **kwargs: Any) -> Any:
        """A session started at once, named ``s<n>``."""
        self.started: list[tuple[str, tuple[float, ...], str]] = [
            *getattr(self, "started", []), (stream_id, tuple(box), preset)]
        return SimpleNamespace(session_id=f"s{len(self.started)}")


@pytest.fixture
def offline_client() -> OfflineClient:
    """A stand-in for a service client, for adapter tests that need no service."""
    return OfflineClient()


@dataclass
class EarlyAdapter:
    """An adapter's command started before the service: its process, the lines of its
    stderr so far (a reader thread appends them) and, once it is over, its exit status."""

    proc: subprocess.Popen[str]
    lines: list[str] = field(default_factory=list)
    code: int | None = None


@contextmanager
def _started_before_the_service(cmd: list[str], endpoint: str) -> Iterator[EarlyAdapter]:
    from arcf.loadtools.procs import ServiceProcess
    from arcf.loadtools.waiting import wait_until

    early = EarlyAdapter(subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True))
    assert early.proc.stderr is not None
    reader = threading.Thread(target=lambda: early.lines.extend(early.proc.stderr or []),
                              daemon=True)
    reader.start()
    try:
        wait_until(lambda: any("waiting for the tracking service" in x for x in early.lines),
                   timeout=60, what="a line saying what it waits for")
        with ServiceProcess(workers=1, listen=endpoint):
            yield early
    finally:
        if early.proc.poll() is None:
            early.proc.terminate()
        try:
            early.code = early.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            early.proc.kill()
            early.proc.wait()
        reader.join(10)


@pytest.fixture
def started_before_the_service() -> Callable[[list[str], str],
                                             AbstractContextManager[EarlyAdapter]]:
    """``with started_before_the_service(cmd, endpoint) as early``: the adapter's ``cmd``
    (its ``-e endpoint``, a free port) runs with no service until it says it waits for one;
    then a one-worker service listens on ``endpoint`` for the block. After the block the
    service is stopped, and the adapter, if still running, terminated: ``early.code`` is its
    exit status. One helper because the start-order tests of ``arcf-record`` and
    ``arcf-ingest`` play this same sequence."""
    return _started_before_the_service
