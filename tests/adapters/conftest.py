"""What the adapters' tests share."""

from __future__ import annotations

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
