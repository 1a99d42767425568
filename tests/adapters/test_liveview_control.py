"""Click to track in the live view: a box dragged on the picture in a real headless browser
(Debian's Chromium, a real pointer through Playwright) starts a session on a stream that had
none, a second one re-initialises it, a button stops it; a stream is listed before any session
tracks it. Control is off unless the operator turns it on, and a request that does not come
from the view's own page is refused and counted."""

from __future__ import annotations

import json
import shutil
import threading
import urllib.error
import urllib.request
from collections.abc import Iterator
from typing import Any

import pytest

pytest.importorskip("zenoh")

from arcf.adapters.liveview import MAX_BODY, LiveView
from arcf.client import TrackingClient
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import wait_until

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.integration
#: frames the camera sends at most (bounded: 2 minutes at 10 fps)
MAX_FRAMES = 1200


@pytest.fixture(scope="module")
def service() -> Iterator[ServiceProcess]:
    with ServiceProcess("--stale-after-s", "0", workers=1) as svc:
        yield svc


class Camera:
    """A station publishing a real sequence's JPEG frames at 10 fps, with no session."""

    def __init__(self, client: TrackingClient, stream: str, data: list[bytes]) -> None:
        self.stop = threading.Event()
        self.sent = 0

        def run() -> None:
            for i in range(MAX_FRAMES):
                if self.stop.wait(0.1):  # the stimulus: a 10 fps camera
                    return
                client.publish_frame(stream, data=data[i % len(data)], seq=i)
                self.sent = i + 1

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=10)


def post(url: str, body: Any, headers: dict[str, str] | None = None,
         raw: bytes | None = None) -> tuple[int, dict[str, Any]]:
    req = urllib.request.Request(url, data=raw if raw is not None else json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json", **(headers or {})},
                                 method="POST")
    try:
        with urllib.request.urlopen(req, timeout=10) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read() or b"{}")


@pytest.mark.skipif(CHROMIUM is None, reason="needs Chromium (apt: chromium)")
def test_a_dragged_box_starts_then_reinitialises_then_stops_a_session(
        service: ServiceProcess, wakeboard7) -> None:
    from playwright.sync_api import sync_playwright

    seq = wakeboard7
    data = [p.read_bytes() for p in seq.frames[:60]]
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as station, \
            TrackingClient(connect=[service.endpoint]) as viewer:
        camera = Camera(station, "cam-9", data)
        view = LiveView(viewer, "127.0.0.1", 0, max_fps=5, max_width=960, allow_control=True)
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
                # the address without the token only watches
                watcher = browser.new_page()
                watcher.goto(view.url + "?stream=cam-9")
                watcher.wait_for_function(
                    "document.getElementById('control-hint').textContent.includes('token')",
                    timeout=30_000)
                assert not watcher.locator("#sessions button.stop").count()
                watcher.close()
                page = browser.new_page(viewport={"width": 1300, "height": 1000})
                page.goto(view.control_url)
                # the token is kept for the tab and taken out of the address
                page.wait_for_function("!location.hash", timeout=30_000)
                # listed with no session (the station announces what it publishes)
                link = page.locator("#streams a", has_text="cam-9")
                link.wait_for(timeout=30_000)
                assert "no session" in page.inner_text("#streams li:has(a)")
                link.click()
                page.wait_for_function(
                    "document.getElementById('video').naturalWidth > 0 && "
                    "window.arcfView.control.ready", timeout=30_000)
                assert "drag a box" in page.inner_text("#control-hint")
                page.select_option("#preset", "bacf")

                def drag(box: tuple[float, float, float, float]) -> None:
                    """A pointer drag over ``box`` (1-based frame pixels) on the picture."""
                    area = page.locator("#draw").bounding_box()
                    assert area is not None
                    k = area["width"] / 1280  # the page shows the 1280-wide frame scaled
                    x, y, w, h = box
                    left, top = area["x"] + (x - 1) * k, area["y"] + (y - 1) * k
                    page.mouse.move(left, top)
                    page.mouse.down()
                    page.mouse.move(left + w * k / 2, top + h * k / 2, steps=4)
                    page.mouse.move(left + w * k, top + h * k, steps=4)
                    page.mouse.up()

                first = (500.0, 300.0, 80.0, 60.0)
                results = viewer.results("cam-9")  # before the drag: its first result too
                drag(first)
                page.wait_for_function("window.arcfView.control.last !== null", timeout=30_000)
                reply = page.evaluate("window.arcfView.control.last")
                assert reply["status"] == 201, reply
                sid = reply["session_id"]
                (info,) = viewer.status("cam-9").sessions
                assert info.session_id == sid and info.preset == "bacf"
                # its first result: initialised on the box drawn (to a pixel: the pointer
                # moves in CSS pixels of a picture shown at 960 / 1280 of the frame's)
                init = next(r for r in results.iter(timeout=30) if r.status.value != "stale")
                assert init.session_id == sid
                assert init.status.value == "initialized"
                assert all(abs(a - b) <= 1.5 for a, b in zip(init.box, first, strict=True)), \
                    init.box
                page.wait_for_selector(f"#sessions tr[data-session='{sid}']", timeout=30_000)

                # re-drawn: the row's button, then a new box
                page.click(f"#sessions tr[data-session='{sid}'] button.select")
                assert "re-initialise" in page.inner_text("#control-hint")
                second = (300.0, 200.0, 60.0, 90.0)
                drag(second)
                page.wait_for_function(
                    "window.arcfView.control.last && window.arcfView.control.last.status "
                    "=== 200", timeout=30_000)
                again = next(r for r in results.iter(timeout=30)
                             if r.status.value == "reinitialized")
                assert all(abs(a - b) <= 1.5 for a, b in zip(again.box, second, strict=True))
                assert viewer.status("cam-9").sessions[0].session_id == sid  # the same one

                # stopped from its row
                page.click(f"#sessions tr[data-session='{sid}'] button.stop")
                wait_until(lambda: viewer.status("cam-9").sessions == [], timeout=30,
                           what="the session stopped")
                page.wait_for_function(
                    "document.getElementById('control-state').textContent.includes('stopped')",
                    timeout=30_000)
                browser.close()
        finally:
            view.close()
            camera.close()
    assert view.counts.get("control_control_off", 0) == 0


def test_control_is_off_unless_turned_on_and_only_the_views_page_may_use_it(
        service: ServiceProcess) -> None:
    box = {"box": [500, 300, 80, 60], "preset": "bacf"}
    with TrackingClient(connect=[service.endpoint]) as viewer:
        off = LiveView(viewer, "127.0.0.1", 0)
        try:
            assert json.loads(urllib.request.urlopen(off.url + "api/config", timeout=10)
                              .read())["control"] is False
            code, reply = post(off.url + "api/streams/cam-x/sessions", box)
            assert code == 403 and reply["code"] == "control_off"
            assert "--allow-control" in reply["message"]
        finally:
            off.close()
        assert viewer.status("cam-x").sessions == []
        assert off.counts == {"control_control_off": 1}

        on = LiveView(viewer, "127.0.0.1", 0, allow_control=True)
        url = on.url + "api/streams/cam-x/sessions"
        token = on.control.token
        try:
            refusals = [
                # whoever reaches the page without the view's token
                ({"Authorization": ""}, box, "bad_credential", 401),
                ({"Authorization": "Bearer " + token[:-1] + "x"}, box, "bad_credential", 401),
                ({"Authorization": "Basic " + token}, box, "bad_credential", 401),
                # another site open in the operator's browser
                ({"Origin": "http://evil.example"}, box, "bad_origin", 403),
                # a name rebound to this machine (DNS rebinding): its own Host header
                ({"Host": "evil.example:8090"}, box, "bad_host", 403),
                ({"Content-Type": "text/plain"}, box, "bad_request", 415),
                ({}, {"box": [1, 2, 3]}, "bad_request", 400),
                ({}, {"box": [1, 2, -3, 4]}, "bad_request", 400),
                ({}, {"box": [1, 2, 3, 4], "preset": "bacf", "path": "/etc"}, "bad_request",
                 400),
                ({}, {"box": [1, 2, 3, 4], "frame_seq": -1}, "bad_request", 400),
            ]
            for headers, body, code_wanted, status_wanted in refusals:
                status, reply = post(url, body, {"Authorization": f"Bearer {token}", **headers})
                assert (status, reply["code"]) == (status_wanted, code_wanted), (headers, body)
            auth = {"Authorization": f"Bearer {token}"}
            status, reply = post(url, None, auth, raw=b"{not json")
            assert status == 400 and reply["code"] == "bad_request"
            status, _ = post(url, None, auth, raw=b"x" * (MAX_BODY + 1))
            assert status == 413
            # the service's own refusals, with its code
            status, reply = post(url, {"box": [1, 2, 3, 4], "preset": "kcf"}, auth)
            assert status == 422 and reply["code"] == "unknown_preset"
            status, reply = post(on.url + "api/sessions/nobody/stop", {}, auth)
            assert status == 404 and reply["code"] == "unknown_session"
            assert viewer.status("cam-x").sessions == []  # nothing was started
            # the page's own request (its origin, JSON, the token): started; then stopped
            status, reply = post(url, box, {"Origin": on.url.rstrip("/"), **auth})
            assert status == 201
            sid = reply["session_id"]
            assert [s.session_id for s in viewer.status("cam-x").sessions] == [sid]
            # without the token, even the view's own page cannot stop it
            status, reply = post(on.url + f"api/sessions/{sid}/stop", {})
            assert status == 401 and reply["code"] == "bad_credential"
            status, _ = post(on.url + f"api/sessions/{sid}/stop", {}, auth)
            assert status == 200 and viewer.status("cam-x").sessions == []
            metrics_text = urllib.request.urlopen(on.url + "metrics", timeout=10).read().decode()
        finally:
            on.close()
        counted = sum(v for k, v in on.counts.items() if k.startswith("control_"))
        # the bad JSON, the service's two refusals, the stop without the token
        assert counted == len(refusals) + 2 + 2 + 1
        assert on.counts["control_bad_credential"] == 3 + 1
        # the same on the page's Prometheus endpoint
        from arcf.service.scrape import by_label

        exposed = by_label(metrics_text, "arcf_view_events_total", "reason")
        assert {k: int(v) for k, v in exposed.items()} == on.counts
        assert on.counts["control_bad_request"] == 5 + 1 + 1  # the body too large, counted


def test_opened_mid_stream_on_the_video_key_each_box_is_drawn_on_its_own_picture(
        service: ServiceProcess, wakeboard7) -> None:
    """CompressedVideo units carry no number: the service numbers them from its subscription,
    the view from its own, which starts later. Each result still lands on its own picture
    (the one whose capture time it carries), and the picture's number is not claimed."""
    import time

    import zenoh

    from arcf.client.foxglove import compressed_video
    from arcf.client.media.images import decode_compressed
    from arcf.loadtools.video import encode_video

    images = [decode_compressed(p.read_bytes()) for p in wakeboard7.frames[:30]]
    units = encode_video(images, "h264", fps=10, gop=10, repeat_headers=True)
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        pub = client.session.declare_publisher("video/mid/stream",
                                               congestion_control=zenoh.CongestionControl.BLOCK)
        ack = client.start("mid", wakeboard7.init_box, preset="bacf")
        results = client.results("mid", ack.session_id)
        sent: dict[int, int] = {}  # capture time -> the service's number (its arrival order)

        def send(i: int) -> None:
            ts = time.time_ns()
            sent[ts] = i
            pub.put(compressed_video(units[i % len(units)], "h264", ts))

        for i in range(15):  # before anyone watches
            send(i)
        wait_until(lambda: any(r.frame_seq >= 14 for r in results.iter(timeout=1)),
                   timeout=60, what="the service's first 15 units answered")
        view = LiveView(client, "127.0.0.1", 0, max_fps=10, max_width=640)
        try:
            # a viewer of its results: the stream is watched from now on
            events = urllib.request.urlopen(view.url + "api/streams/mid/results", timeout=30)
            watch = view.watches["mid"]
            n = 15

            def matched() -> bool:
                """A picture drawn with the result about it (a session that lags more than
                the view's recent frames is drawn, by design, on a newer picture: on a loaded
                machine the first pictures may be such)."""
                with watch.changed:
                    return any(r.capture_ts_ns == watch.rendered_key for r in watch.drawn)

            while not matched():
                assert n < 15 + 150, "no picture drawn with its own result"  # 15 s of video
                send(n)
                n += 1
                time.sleep(0.1)  # the stimulus: a 10 fps camera
            with watch.changed:
                key, drawn, seq = watch.rendered_key, list(watch.drawn), watch.rendered_seq
            (r,) = drawn
            assert key is not None and sent[key] == r.frame_seq  # the service's number of it
            assert seq is None  # the view does not know the service's number of it
            reply = urllib.request.urlopen(view.url + "api/streams/mid/frame.jpg?after=0",
                                           timeout=30)
            assert reply.headers.get("X-Frame-Seq") is None
            assert reply.headers.get("X-Frame-Width") == "1280"
            events.close()
        finally:
            view.close()
            results.close()
            pub.undeclare()
