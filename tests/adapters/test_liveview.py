"""The live view in a real headless browser (Debian's Chromium, driven by Playwright): the page
loads from the package alone (no request leaves loopback), lists the stream, shows its video
with the session's box drawn in the session's colour where the service put it, and updates;
a stream that stops shows its session as stale (no frames) until its frames resume."""

from __future__ import annotations

import shutil
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

pytest.importorskip("zenoh")
pytest.importorskip("playwright.sync_api")

from playwright.sync_api import sync_playwright

from arcf.adapters.liveview import LiveView, colour_bgr
from arcf.client import TrackingClient
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import wait_until

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(CHROMIUM is None, reason="needs Chromium (apt: chromium)")]


@pytest.fixture(scope="module")
def frames(wakeboard7):
    return wakeboard7, [p.read_bytes() for p in wakeboard7.frames[:60]]


def test_the_page_shows_the_stream_with_its_boxes_and_updates(frames, tmp_path: Path) -> None:
    seq, data = frames
    stop = threading.Event()
    # the last frame's box is looked at after the stream ends: without stale notices (their
    # own test is below), which would grey it a second later
    with ServiceProcess("--stale-after-s", "0", workers=1) as service, \
            TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        ack = client.start("drone-7", seq.init_box, preset="bacf", frame_seq=0)
        results = client.results("drone-7", ack.session_id)

        view = LiveView(client, "127.0.0.1", 0, max_fps=5, max_width=960)
        shown = threading.Event()  # the page shows the stream: the rest of the clip may come

        def publish() -> None:  # 10 fps, bounded: the clip once, then stop
            # from the page's arrival (the view listens from then on), ten frames, then the
            # rest once the page shows them: however slow the machine, the page sees it move
            wait_until(lambda: "drone-7" in view.watches, timeout=60, what="the page watching")
            for i, d in enumerate(data):
                if i == 10 and not shown.wait(timeout=120):
                    return  # the page never came up: the test fails on its own wait
                if stop.wait(0.1):  # the stimulus: a 10 fps camera
                    return
                client.publish_frame("drone-7", data=d, seq=i)

        sender = threading.Thread(target=publish, daemon=True)
        outside: list[str] = []
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1300, "height": 1000})
                page.on("request", lambda r: None if r.url.startswith(
                    (view.url, "blob:" + view.url.rstrip("/"))) else outside.append(r.url))
                page.goto(view.url + "?stream=drone-7")
                sender.start()
                page.wait_for_selector("#streams a.current", timeout=15_000)
                assert page.inner_text("#streams a.current") == "drone-7"
                page.wait_for_function(
                    "document.getElementById('video').naturalWidth > 0 && "
                    "window.arcfView.points() > 5", timeout=60_000)
                first = int(page.inner_text("#frame-seq"))  # at most 9: the rest waits
                shown.set()
                page.wait_for_function(
                    f"Number(document.getElementById('frame-seq').textContent) > {first + 5}",
                    timeout=30_000)  # it updates: later frames, more points
                assert page.inner_text("#sessions tbody td:nth-child(2)") == "bacf"
                # the last frame, its box drawn: stop the stream, let the view catch up
                sender.join(timeout=60)
                assert not sender.is_alive()
                last = None
                # the newest frame is never the one a queue sheds: the last frame is answered
                for r in results.iter(timeout=30.0):
                    last = r
                    if r.frame_seq == len(data) - 1:
                        break
                assert last is not None and last.frame_seq == len(data) - 1
                page.wait_for_function(
                    f"document.getElementById('frame-seq').textContent == '{len(data) - 1}'",
                    timeout=30_000)
                watch = view.watches["drone-7"]
                # rendered at 5 fps: until the final frame is rendered with its box
                wait_until(lambda: watch.rendered_seq == len(data) - 1 and len(watch.drawn) == 1
                           and watch.drawn[0].frame_seq == len(data) - 1, timeout=30,
                           what="the final frame rendered with its box")
                (drawn,) = watch.drawn
                assert drawn.frame_seq == last.frame_seq and drawn.box == last.box
                page.wait_for_function(  # the page shows that picture
                    f"document.getElementById('video').dataset.frameSeq == '{len(data) - 1}'",
                    timeout=15_000)
                img = page.locator("#video")
                shot = tmp_path / "video.png"
                img.screenshot(path=str(shot))
                natural = page.evaluate("document.getElementById('video').naturalWidth")
                browser.close()
        finally:
            stop.set()
            view.close()
    pixels = cv2.imread(str(shot)).astype(float)
    assert natural == 960 and pixels.shape[1] == 960  # scaled to max_width, shown as rendered
    x, y, w, h = (v * 960 / 1280 for v in last.box)
    x, y = x - 960 / 1280, y - 960 / 1280
    want = np.array(colour_bgr(0), dtype=float)  # the first session's colour

    def near(px: float, py: float) -> float:
        """How far the closest pixel within 2 px is from the session's colour."""
        c, r = round(px), round(py)
        patch = pixels[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3].reshape(-1, 3)
        return float(np.abs(patch - want).max(axis=1).min())

    # along the box's four edges: the session's colour (JPEG blurs it a little)
    edges = [near(x + f * w, y) for f in np.linspace(0.1, 0.9, 5)]
    edges += [near(x + f * w, y + h) for f in np.linspace(0.1, 0.9, 5)]
    edges += [near(x, y + f * h) for f in np.linspace(0.1, 0.9, 5)]
    edges += [near(x + w, y + f * h) for f in np.linspace(0.1, 0.9, 5)]
    assert sum(d < 80 for d in edges) >= 18, edges
    # and the scene's own colours away from it (the box is drawn, not the frame green)
    far = [near(x + w / 2, y + h + 40), near(x - 40, y + h / 2)]
    assert min(far) >= 80, far
    assert outside == []  # nothing from a CDN or anywhere else: it works offline
    # once nobody watches, nothing is listened to
    wait_until(lambda: view.watches == {}, timeout=30, what="no watch left without a viewer")


def test_unknown_paths_and_too_many_viewers_are_refused() -> None:
    class Quiet:
        def status(self, timeout: float = 0) -> None:
            raise TimeoutError("no service")

    view = LiveView(Quiet(), "127.0.0.1", 0, max_viewers=1)  # type: ignore[arg-type]
    try:
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(view.url + "etc/passwd", timeout=5)
        assert e.value.code == 404
        doc = urllib.request.urlopen(view.url + "api/streams", timeout=5).read().decode()
        assert "no answer from the service" in doc
        page = urllib.request.urlopen(view.url, timeout=5).read().decode()
        assert "<script src=\"/view.js\">" in page and "http" not in page.split("<body>")[1]
    finally:
        view.close()


def test_a_stream_that_stops_shows_its_session_stale_until_frames_resume(frames) -> None:
    seq, data = frames
    with ServiceProcess(workers=1) as service, \
            TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        view = LiveView(client, "127.0.0.1", 0, max_fps=5, max_width=960)
        ack = client.start("drone-8", seq.init_box, preset="bacf", frame_seq=0)
        results = client.results("drone-8", ack.session_id)

        state = "#sessions tbody tr td:nth-child(3)"

        def feed(n: int, until: str, also: Any = lambda: True) -> int:
            """Frames n.. at 10 fps until the page's ``until`` (a JavaScript condition) and
            ``also()`` hold, so that the stream stays live however long the page takes to show
            it; the next frame's number."""
            deadline = time.monotonic() + 60
            while not (page.evaluate(until) and also()):
                assert time.monotonic() < deadline, f"not shown within 60 s: {until}"
                client.publish_frame("drone-8", data=data[n % len(data)], seq=n)
                n += 1
                time.sleep(0.1)  # the stimulus: a 10 fps camera
            return n

        # tracking (or coasting) shown, with its points: not stale
        tracking = (f"window.arcfView && window.arcfView.points() > 0 && "
                    f"!!document.querySelector('{state}') && "
                    f"!document.querySelector('{state}').textContent.includes('stale')")

        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1300, "height": 1000})
                page.goto(view.url + "?stream=drone-8")
                page.wait_for_function("window.arcfView !== undefined", timeout=30_000)
                n = feed(0, tracking)
                # the stimulus: the frames stop. The service's notice about the last frame
                # (any earlier one, of a pause of this machine's, is not what is looked at)
                notice = None
                for r in results.iter(timeout=30):
                    if r.status.value == "stale" and r.frame_seq == n - 1:
                        notice = r
                        break
                assert notice is not None and notice.code.value == "no_frames"
                page.wait_for_function(
                    f"document.querySelector('{state}').textContent == 'stale: no frames'",
                    timeout=30_000)
                assert page.get_attribute("#sessions tbody tr", "class") == "stale"
                # the reason in full, as the service gave it
                page.wait_for_function(
                    "document.querySelector('#sessions tbody tr').title.length > 0",
                    timeout=30_000)
                assert "not current" in page.get_attribute("#sessions tbody tr", "title")
                watch = view.watches["drone-8"]
                wait_until(lambda: watch.drawn and watch.drawn[0].status.value == "stale", 30,
                           f"the picture drawn again (view {view.counts}, {watch.viewers} "
                           "viewers when the wait began)")
                assert watch.drawn[0].frame_seq == notice.frame_seq  # its last box, marked
                # frames again: tracking results, the row leaves "stale" and so does the
                # picture (fed until both show it)
                feed(n, tracking, also=lambda: bool(watch.drawn)
                     and watch.drawn[0].status.value != "stale")
                browser.close()
        finally:
            view.close()
