"""The README's picture of the live view, made the way an operator would get it: a camera
publishing a shared sequence at 10 fps to a one-worker service with no session, ``arcf-view
--allow-control`` in headless Chromium, the target's box dragged on the picture with a real
pointer (which starts the session), then a few seconds of tracking and a screenshot.

    python tools/liveview_picture.py                      # writes docs/img/liveview.png
    python tools/liveview_picture.py --sequence wakeboard10 --preset arcf-h --out /tmp/v.png
"""

from __future__ import annotations

import argparse
import shutil
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STREAM = "drone-7"
WIDTH = 960  # the view's max_width: the picture is shown scaled to it


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default="boat1", help="a UAV123@10fps sequence")
    ap.add_argument("--preset", default="arcf-hc")
    ap.add_argument("--frames", type=int, default=45, help="frames tracked before the shot")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "liveview.png")
    args = ap.parse_args(argv)
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        print("needs Chromium (apt: chromium)", file=sys.stderr)
        return 2

    from playwright.sync_api import sync_playwright

    from arcf.adapters.liveview import LiveView
    from arcf.client import TrackingClient
    from arcf.eval import load_dataset
    from arcf.loadtools.procs import ServiceProcess
    from arcf.loadtools.waiting import wait_until

    (seq,) = load_dataset("uav123_10fps", sequences=[args.sequence])
    data = [p.read_bytes() for p in seq.frames]
    stop = threading.Event()
    with ServiceProcess("--stale-after-s", "0", workers=1) as service, \
            TrackingClient(connect=[service.endpoint], frame_congestion="block") as camera, \
            TrackingClient(connect=[service.endpoint]) as viewer:

        def publish() -> None:  # a 10 fps camera, the sequence once at most
            for i, d in enumerate(data):
                if stop.wait(0.1):
                    return
                camera.publish_frame(STREAM, data=d, seq=i)

        sender = threading.Thread(target=publish, daemon=True)
        sender.start()
        view = LiveView(viewer, "127.0.0.1", 0, max_fps=5, max_width=WIDTH, allow_control=True)
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1300, "height": 1000})
                page.goto(view.url + f"?stream={STREAM}#token={view.control.token}")
                page.wait_for_function(
                    "document.getElementById('video').naturalWidth > 0 && "
                    "window.arcfView.control.ready", timeout=60_000)
                page.select_option("#preset", args.preset)
                shown = int(page.evaluate("document.getElementById('video').dataset.frameSeq"))
                area = page.locator("#draw").bounding_box()
                assert area is not None
                k = area["width"] / seq.read_frame(0).shape[1]
                x, y, w, h = seq.groundtruth[shown]  # the pilot draws around the target
                left, top = area["x"] + (x - 1) * k, area["y"] + (y - 1) * k
                page.mouse.move(left, top)
                page.mouse.down()
                page.mouse.move(left + w * k, top + h * k, steps=8)
                page.mouse.up()
                page.wait_for_function("window.arcfView.control.last !== null", timeout=30_000)
                reply = page.evaluate("window.arcfView.control.last")
                if reply.get("status") != 201:
                    print(f"the drag did not start a session: {reply}", file=sys.stderr)
                    return 1
                until = min(len(data) - 1, shown + args.frames)
                wait_until(lambda: view.watches[STREAM].rendered_seq >= until, timeout=120,
                           what=f"frame {until} rendered")
                page.wait_for_function("window.arcfView.points() > 5", timeout=30_000)
                page.screenshot(path=str(args.out), full_page=True)
                browser.close()
        finally:
            stop.set()
            view.close()
            sender.join(timeout=10)
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
