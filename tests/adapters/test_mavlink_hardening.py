"""The MAVLink camera against a hostile link (real UDP on loopback, a pymavlink station): what
it keeps is bounded whatever is sent (recent commands, peers), frame sizes are read without
decoding and above ``max_pixels`` refused, and with a signing key only signed commands are
obeyed. No service is needed: a command on a stream without frames is denied by the
endpoint itself."""

from __future__ import annotations

import os
import socket
import struct
import time
import zlib
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from arcf.adapters._command import serve_counts
from arcf.adapters.mavlink import (
    DONE_MAX,
    MAX_PEERS,
    CameraConfig,
    MavlinkCameras,
    frame_size,
)
from arcf.loadtools.groundstation import GroundStation
from arcf.loadtools.procs import free_port
from arcf.loadtools.waiting import wait_until as _wait
from arcf.schemas import Frame
from arcf.service.scrape import fetch, series

mav = mavutil.mavlink
STREAM, COMP = "cam1", 100
KEY = bytes(range(32))


def endpoint_on(client: Any, port: int, **kwargs: Any) -> MavlinkCameras:
    return MavlinkCameras(client, f"udpin:127.0.0.1:{port}", [CameraConfig(STREAM, COMP)],
                          link_timeout_s=2.0, status_interval_s=0.0, **kwargs).start()


def test_refused_commands_are_remembered_in_a_bounded_table(offline_client: Any) -> None:
    """2 x DONE_MAX distinct rectangles, each denied (no frames yet), each acknowledged:
    the table of recent results never holds more than DONE_MAX."""
    port = free_port()
    endpoint = endpoint_on(offline_client, port)
    station = GroundStation(port, COMP)
    try:
        _wait(lambda: endpoint.link_up)
        sizes = []
        for k in range(2 * DONE_MAX):
            x = 0.1 + 0.3 * k / (2 * DONE_MAX)
            station.conn.mav.command_long_send(1, COMP, mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0,
                                               x, 0.1, x + 0.2, 0.4, 0, 0, 0)
            if k % 64 == 63:
                _wait(lambda k=k: len(station.since(0, "COMMAND_ACK")) == k + 1, timeout=20)
                sizes.append(len(endpoint._done))
        acks = station.since(0, "COMMAND_ACK")
        assert len(acks) == 2 * DONE_MAX
        assert {a.result for a in acks} == {mav.MAV_RESULT_DENIED}
        assert max(sizes) <= DONE_MAX and sizes[-1] == DONE_MAX
    finally:
        station.close()
        endpoint.close()


def test_a_listening_link_answers_a_bounded_set_of_peers_stations_first(
        offline_client: Any) -> None:
    """Packets from 60 source ports (garbage and camera-less noise): the link keeps at most
    MAX_PEERS addresses, the station that sent heartbeats among them, and its commands are
    still answered."""
    port = free_port()
    endpoint = endpoint_on(offline_client, port)
    station = GroundStation(port, COMP)
    try:
        _wait(lambda: endpoint.link_up)
        sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(60)]
        try:
            for s in sockets:
                s.sendto(b"\xfd\x09garbage", ("127.0.0.1", port))
            _wait(lambda: endpoint.counts["peers_forgotten"] >= 60 - MAX_PEERS, timeout=10)
        finally:
            for s in sockets:
                s.close()
        clients = endpoint.conn.clients  # type: ignore[attr-defined]
        assert len(clients) <= MAX_PEERS
        station_port = station.conn.port.getsockname()[1]  # type: ignore[attr-defined]
        assert ("127.0.0.1", station_port) in clients, (endpoint._stations, clients)
        t0 = time.monotonic()
        station.conn.mav.command_long_send(1, COMP, mav.MAV_CMD_CAMERA_STOP_TRACKING, 0,
                                           0, 0, 0, 0, 0, 0, 0)
        _wait(lambda: station.since(t0, "COMMAND_ACK"), timeout=10)
    finally:
        station.close()
        endpoint.close()


def _png_header(width: int, height: int) -> bytes:
    body = struct.pack(">IIBBBBB", width, height, 16, 6, 0, 0, 0)  # RGBA, 16 bits
    return (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(body)) + b"IHDR" + body
            + struct.pack(">I", zlib.crc32(b"IHDR" + body)))


def test_frame_sizes_are_read_from_headers_and_bounded() -> None:
    """A 12000 x 12000 RGBA-16 PNG (1.1 GB decoded) is refused from its header alone; a
    declared raw size and a 4K header are read as they are."""
    bomb = Frame(stream_id=STREAM, seq=1, capture_ts_ns=1, encoding="png",
                 payload=_png_header(12000, 12000))
    with pytest.raises(ValueError, match="12000x12000 is above 8847360 pixels"):
        frame_size(bomb)
    assert frame_size(bomb, max_pixels=12000 * 12000) == (12000, 12000)
    four_k = Frame(stream_id=STREAM, seq=1, capture_ts_ns=1, encoding="png",
                   payload=_png_header(3840, 2160))
    assert frame_size(four_k) == (3840, 2160)
    with pytest.raises(ValueError, match="no size"):
        frame_size(Frame(stream_id=STREAM, seq=1, capture_ts_ns=1, encoding="jpeg",
                         payload=b"not a jpeg"))
    raw = Frame(stream_id=STREAM, seq=1, capture_ts_ns=1, encoding="gray8", width=4, height=2,
                payload=bytes(8))
    assert frame_size(raw) == (4, 2)


def test_with_a_signing_key_only_signed_commands_are_obeyed(offline_client: Any) -> None:
    """An unsigned station's command is dropped (counted, never carried out); a station
    holding the key is answered, and what the camera sends is signed."""
    port = free_port()
    endpoint = endpoint_on(offline_client, port, signing_key=KEY)
    unsigned = GroundStation(port, COMP)
    unsigned.alive.clear()  # no heartbeats: its command is the only packet it sends
    try:
        unsigned.conn.mav.command_long_send(1, COMP, mav.MAV_CMD_CAMERA_STOP_TRACKING, 0,
                                            0, 0, 0, 0, 0, 0, 0)
        _wait(lambda: endpoint.counts["unsigned"] == 1)
        assert endpoint.counts["commands"] == 0 and not endpoint.link_up
    finally:
        unsigned.close()
    signed = GroundStation(port, COMP)
    signed.conn.setup_signing(KEY, sign_outgoing=True)
    try:
        _wait(lambda: endpoint.link_up)
        t0 = time.monotonic()
        signed.conn.mav.command_long_send(1, COMP, mav.MAV_CMD_CAMERA_STOP_TRACKING, 0,
                                          0, 0, 0, 0, 0, 0, 0)
        _wait(lambda: signed.since(t0, "COMMAND_ACK"))
        ack = signed.since(t0, "COMMAND_ACK")[0]
        assert ack.result == mav.MAV_RESULT_ACCEPTED and ack.get_signed()
        assert endpoint.counts["commands"] == 1 and endpoint.counts["unsigned"] == 1
        # the refusal on the adapter's Prometheus endpoint (arcf-mavlink --metrics-port)
        server, url = serve_counts("mavlink", lambda: endpoint.counts, 0)
        try:
            events = {labels["event"]: value for labels, value in series(fetch(url)).get(
                "arcf_adapter_events_total", []) if labels["adapter"] == "mavlink"}
        finally:
            server.shutdown()
        assert events["unsigned"] == 1 and events["commands"] == 1
    finally:
        signed.close()
        endpoint.close()
    with pytest.raises(ValueError, match="32 bytes"):
        MavlinkCameras(offline_client, f"udpin:127.0.0.1:{free_port()}",
                       [CameraConfig(STREAM, COMP)], signing_key=b"short")
