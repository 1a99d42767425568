"""A MAVLink ground station for tests and benchmarks: what QGroundControl or MAVProxy does on
the link to a camera component (heartbeats, commands, their acknowledgements), over
pymavlink, with every message it receives kept by type."""

from __future__ import annotations

import os
import threading
import time
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

mav = mavutil.mavlink


class GroundStation:
    """A ground station: heartbeats at 2 Hz (while ``alive``), commands, and every message
    it receives kept by type."""

    def __init__(self, port: int, component: int = 100) -> None:
        """A station sending to a camera listening on loopback ``port``; commands go to
        ``component`` unless told otherwise."""
        self.component = component
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                               source_component=mav.MAV_COMP_ID_MISSIONPLANNER)
        self.alive = threading.Event()
        self.alive.set()
        self.received: list[Any] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._beat, daemon=True),
                         threading.Thread(target=self._listen, daemon=True)]
        for t in self._threads:
            t.start()

    def _beat(self) -> None:
        while not self._stop.wait(0.5):
            if self.alive.is_set():
                self.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mav.MAV_STATE_ACTIVE)

    def _listen(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is not None and msg.get_type() != "BAD_DATA":
                with self._lock:
                    self.received.append((time.monotonic(), msg))

    def since(self, t0: float, kind: str) -> list[Any]:
        with self._lock:
            return [m for t, m in self.received if t >= t0 and m.get_type() == kind]

    def command(self, command: int, *params: float, component: int | None = None,
                timeout: float = 10.0, confirmation: int = 0) -> tuple[int, list[str]]:
        """Send a COMMAND_LONG; its COMMAND_ACK's result and the STATUSTEXTs sent with it."""
        t0 = time.monotonic()
        p = [*params, *[0.0] * (7 - len(params))]
        self.conn.mav.command_long_send(1, self.component if component is None else component,
                                        command, confirmation, *p)
        deadline = t0 + timeout
        while time.monotonic() < deadline:
            acks = [a for a in self.since(t0, "COMMAND_ACK") if a.command == command]
            if acks:
                time.sleep(0.05)  # a STATUSTEXT goes just before its ack
                texts = [m.text for m in self.since(t0, "STATUSTEXT")]
                return acks[0].result, texts
            time.sleep(0.01)
        raise AssertionError(f"no COMMAND_ACK for {command} within {timeout} s")

    def request(self, message: int, *params: float, timeout: float = 30.0) -> Any:
        """``MAV_CMD_REQUEST_MESSAGE`` for ``message`` (a message id; ``params`` after it):
        the first such message received after the request, once it is accepted."""
        from .waiting import wait_until

        t0 = time.monotonic()
        result, texts = self.command(mav.MAV_CMD_REQUEST_MESSAGE, message, *params)
        if result != mav.MAV_RESULT_ACCEPTED:
            raise AssertionError(f"request of message {message}: result {result} {texts}")
        name = mav.mavlink_map[message].msgname
        wait_until(lambda: self.since(t0, name), timeout=timeout, what=name)
        return self.since(t0, name)[0]

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2)
        self.conn.close()
