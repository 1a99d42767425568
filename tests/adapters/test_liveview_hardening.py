"""The live view against hostile clients (real sockets on loopback, no browser, no service: the
stream's results are handed to the view as the service would): what one client can hold is
bounded (watching places per address, connections, time to send a request, unread bytes), a
malformed query is answered, and pictures are bounded by their header before decoding."""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from arcf.adapters import liveview
from arcf.adapters.liveview import MAX_PER_CLIENT, LiveView, _picture
from arcf.adapters.tap import TapFrame
from arcf.loadtools.waiting import wait_until
from arcf.schemas import Result

STREAM = "s1"


@pytest.fixture
def view(offline_client: Any, monkeypatch: pytest.MonkeyPatch) -> Iterator[LiveView]:
    monkeypatch.setattr(liveview, "TIMEOUT_S", 1.0)
    monkeypatch.setattr(liveview, "MAX_CONNECTIONS", 8)
    monkeypatch.setattr(liveview, "MAX_UNSENT", 4096)
    monkeypatch.setattr(liveview, "POLL_S", 0.2)
    monkeypatch.setattr(liveview, "KEEPALIVE_S", 0.2)
    v = LiveView(offline_client, "127.0.0.1", 0, video_key=None)
    yield v
    v.close()


def connect(view: LiveView, source: str = "127.0.0.1", rcvbuf: int | None = None
            ) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if rcvbuf is not None:  # before connecting: the window it advertises
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.bind((source, 0))
    s.settimeout(5.0)
    s.connect(("127.0.0.1", view.port))
    return s


def get(s: socket.socket, path: str) -> bytes:
    """Send a GET and return the response's status line and headers."""
    s.sendall(f"GET {path} HTTP/1.1\r\nHost: view\r\n\r\n".encode())
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = s.recv(1)
        if not chunk:
            break
        head += chunk
    return head


def result(k: int) -> Result:
    return Result(session_id="a1", stream_id=STREAM, frame_seq=k, capture_ts_ns=1,
                  box=[10.0, 10.0, 20.0, 20.0], peak=0.5, psr=9.0, aberrance=0.01,
                  aberrance_release=0.01, scale=1.0, status="tracking", dropped=0,
                  received_ts_ns=1, decode_s=0.0, track_s=0.0, published_ts_ns=1,
                  message="x" * 400)


def test_one_address_holds_at_most_its_share_of_viewer_places(view: LiveView) -> None:
    """Results connections that never read, from one address: the fifth is refused (503,
    saying why, counted); another address still gets in; a place comes back when its
    connection closes."""
    held = [connect(view) for _ in range(MAX_PER_CLIENT)]
    try:
        for s in held:
            assert get(s, f"/api/streams/{STREAM}/results").startswith(b"HTTP/1.1 200")
        with connect(view) as extra:
            head = get(extra, f"/api/streams/{STREAM}/results")
            assert head.startswith(b"HTTP/1.1 503")
            assert b"too many viewers from 127.0.0.1" in extra.recv(200)
        with connect(view, source="127.0.0.2") as other:
            assert get(other, f"/api/streams/{STREAM}/results").startswith(b"HTTP/1.1 200")
        held.pop().close()
        wait_until(lambda: view._by_client.get("127.0.0.1") == MAX_PER_CLIENT - 1,
                   what="the closed connection's place freed")
        with connect(view) as again:
            assert get(again, f"/api/streams/{STREAM}/results").startswith(b"HTTP/1.1 200")
        assert view.counts == {"refused_viewer": 1}
    finally:
        for s in held:
            s.close()


def test_a_results_viewer_that_stops_reading_is_dropped(view: LiveView,
                                                        offline_client: Any) -> None:
    """A viewer with a small window that reads nothing while 2,000 results arrive: dropped
    once its unread bytes pass MAX_UNSENT (or a write times out), its place freed."""
    with connect(view, rcvbuf=4096) as lazy:
        assert get(lazy, f"/api/streams/{STREAM}/results").startswith(b"HTTP/1.1 200")
        wait_until(lambda: "results" in offline_client.callbacks, what="the stream watched")
        for k in range(2000):
            offline_client.callbacks["results"](result(k))
        wait_until(lambda: view.counts.get("slow_viewer") == 1, what="the lazy viewer dropped")
        wait_until(lambda: view._viewers == 0 and not view.watches, what="its place freed")


def test_half_sent_requests_cannot_hold_every_connection(
        view: LiveView, monkeypatch: pytest.MonkeyPatch) -> None:
    """MAX_CONNECTIONS (8 here) connections that send half a request line: one more is closed
    at once, counted; each half-sent one is closed after TIMEOUT_S (1 s here), and the view
    answers again. One address alone holds at most MAX_CONNECTIONS_PER_CLIENT (here 6): the
    rest go to another."""
    monkeypatch.setattr(liveview, "MAX_CONNECTIONS_PER_CLIENT", 6)
    stuck = [connect(view) for _ in range(6)] + [connect(view, "127.0.0.3") for _ in range(2)]
    try:
        for s in stuck:
            s.sendall(b"GET / HT")
        wait_until(lambda: view.server._open._value == 0,  # type: ignore[attr-defined]
                   what="every connection taken")
        for source in ("127.0.0.1", "127.0.0.2"):  # over its share; over the total
            with connect(view, source) as extra:
                extra.sendall(b"GET / HTTP/1.1\r\nHost: view\r\n\r\n")
                assert extra.recv(100) == b""  # closed unanswered
        assert view.counts.get("refused_connection") == 2
        for s in stuck:  # the server gives up on each, and closes it
            assert s.recv(100) == b""
        with connect(view) as fresh:
            assert get(fresh, "/").startswith(b"HTTP/1.1 200")
    finally:
        for s in stuck:
            s.close()


def test_a_query_that_is_not_a_number_is_answered(view: LiveView) -> None:
    """``?after=`` with 5,000 digits (beyond what Python turns into an int by default) or
    junk: ignored, and the request answered (no picture yet: 204)."""
    for query in ("9" * 5000, "-" + "9" * 30, "abc", ""):
        with connect(view) as s:
            head = get(s, f"/api/streams/{STREAM}/frame.jpg?after={query}")
            assert head.startswith(b"HTTP/1.1 204"), (query[:20], head)


def _png_header(width: int, height: int) -> bytes:
    body = struct.pack(">IIBBBBB", width, height, 16, 6, 0, 0, 0)  # RGBA, 16 bits
    return (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(body)) + b"IHDR" + body
            + struct.pack(">I", zlib.crc32(b"IHDR" + body)))


def test_pictures_are_bounded_by_their_header() -> None:
    """A 12000 x 12000 RGBA-16 PNG (1.1 GB decoded) and an oversized raw frame are refused
    without decoding; a small real one is drawn."""
    def frame(encoding: str, payload: bytes, w: int | None = None,
              h: int | None = None) -> TapFrame:
        return TapFrame(STREAM, 1, 1, encoding, payload, width=w, height=h)

    with pytest.raises(ValueError, match="the limit is 8847360"):
        _picture(frame("png", _png_header(12000, 12000)), 4096 * 2160)
    with pytest.raises(ValueError, match="exceeds 100 pixels"):
        _picture(frame("gray8", bytes(200), 20, 10), 100)
    assert _picture(frame("gray8", bytes(200), 20, 10), 200).shape == (10, 20)


#: run outside the repository: the view, offline, fetching each of its own files
_SERVED = """
import json, sys, types, urllib.request
from arcf.adapters.liveview import _STATIC, LiveView
client = types.SimpleNamespace(results=None, frames=None)
view = LiveView(client, "127.0.0.1", 0, video_key=None)
try:
    got = {}
    for path in _STATIC:
        with urllib.request.urlopen(view.url.rstrip("/") + path, timeout=30) as reply:
            got[path] = [reply.status, len(reply.read())]
    print(json.dumps(got))
finally:
    view.close()
"""


def test_the_page_is_served_by_the_installed_package(tmp_path: Path) -> None:
    """The view's own files come from the installed ``arcf.adapters``, not from a folder that
    only a process started in the repository can see: started elsewhere (``-P``: not even
    the current directory on the path), every static path is answered with its file."""
    static = Path(liveview.__file__).parent / "static"
    run = subprocess.run([sys.executable, "-P", "-c", _SERVED], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got == {path: [200, (static / name).stat().st_size]
                   for path, (name, _) in liveview._STATIC.items()}, run.stderr[-2000:]
