"""Waiting for a condition with a deadline, as tests and benchmarks do instead of fixed
sleeps."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Generic, TypeVar

T = TypeVar("T")


def wait_until(condition: Any, timeout: float = 10.0, what: str = "condition") -> None:
    """Poll ``condition()`` until it is true; AssertionError after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout} s: {what}")
        time.sleep(0.02)


def next_result(results: Any, after_seq: int = -1, timeout: float = 60.0) -> Any:
    """The next result about a frame after ``after_seq`` from a result stream (the client
    SDK's ``results``), stale notices skipped (a loaded machine may pause between frames
    longer than the service's ``stale_after_s``); AssertionError after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            r = results.get(timeout=1.0)
        except Exception:  # queue.Empty
            continue
        if r.status != "stale" and r.frame_seq is not None and r.frame_seq > after_seq:
            return r
    raise AssertionError(f"no result after frame {after_seq} within {timeout:.0f} s")


class Arrivals(Generic[T]):
    """What a callback receives on another thread (a subscription's messages), in arrival
    order, with a wait that wakes on each arrival instead of polling.

    Pass the instance itself as the callback; ``describe`` says how an item is shown when a
    wait runs out.
    """

    def __init__(self, describe: Callable[[T], Any] = repr) -> None:
        self.got: list[T] = []
        self._describe = describe
        self._cond = threading.Condition()

    def __call__(self, item: T) -> None:
        with self._cond:
            self.got.append(item)
            self._cond.notify_all()

    def wait(self, predicate: Callable[[list[T]], object], what: str = "condition",
             timeout: float = 30.0) -> list[T]:
        """A copy of everything received, once ``predicate`` holds for it; AssertionError
        with what did arrive after ``timeout`` seconds (a generous deadline by default, not a
        measurement: a loaded 2-core machine must pass)."""
        with self._cond:
            if not self._cond.wait_for(lambda: predicate(self.got), timeout=timeout):
                raise AssertionError(f"no {what} within {timeout} s: "
                                     f"{[self._describe(x) for x in self.got[-40:]]}")
            return list(self.got)


def wait_for_peers(session: Any, count: int = 1, timeout: float = 30.0) -> None:
    """Until a Zenoh peer session has direct links to ``count`` peers (a station on the
    direct data path, linked to the workers the router's gossip named); AssertionError after
    ``timeout`` seconds."""
    wait_until(lambda: len(list(session.info.peers_zid())) >= count, timeout=timeout,
               what=f"direct links to {count} peer(s)")
