"""``arcf-demo``, the README's first command: a real sequence replayed through a service it
starts, or through one already running (``--connect``) on a named stream; every frame is
answered or counted as dropped, in order, and the last one is answered."""

from __future__ import annotations

import re

import pytest

pytest.importorskip("zenoh")

from arcf.client import TrackingClient
from arcf.data import data_root
from arcf.loadtools import demo
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.waiting import wait_until

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]
FRAMES = 10
LINE = re.compile(r"^frame +(\d+) (\w+) .* dropped (\d+) error", re.M)


def _accounted(out: str) -> list[int]:
    """The frames the demo printed results for, after checking that they come in order, end
    with the last frame, and with the frames reported dropped make up every frame sent. A
    live replay puts frames with DROP: one lost on the way before the session's first result
    is counted by no later ``dropped`` (its box goes to the first frame that arrives), so the
    frames before the first answered one are skipped at the start, as the ledger counts them."""
    found = [(int(n), status, int(d)) for n, status, d in LINE.findall(out)]
    frames = [n for n, _, _ in found]
    assert found and found[0][1] == "initialized", out
    assert frames == sorted(set(frames)) and frames[-1] == FRAMES - 1, frames
    assert frames[0] + len(frames) + sum(d for _, _, d in found[1:]) == FRAMES, found
    assert f"{len(frames)}/{FRAMES} frames tracked" in out
    return frames


def test_the_demo_starts_its_service_and_replays_a_sequence(capsys) -> None:
    port = free_port()
    assert demo.main(["--limit", str(FRAMES), "--preset", "bacf", "--workers", "1",
                      "--port", str(port)]) == 0
    out = capsys.readouterr().out
    assert f"starting arcf-service on tcp/127.0.0.1:{port}" in out
    default_stream = "-".join(("uav123_10fps", "wakeboard7"))  # <dataset>-<sequence>
    assert f"on stream {default_stream}:" in out
    assert "each result: frame, status, box" in out  # what the columns are
    _accounted(out)


def test_the_demo_replays_through_a_running_service_on_a_named_stream(capsys) -> None:
    with ServiceProcess(workers=1) as service, \
            TrackingClient(connect=[service.endpoint]) as watcher:
        seen: list[int] = []
        sub = watcher.results("cam-demo", callback=lambda r: seen.append(r.frame_seq)
                              if r.status.value not in ("stale", "stopped") else None)
        assert demo.main(["--limit", str(FRAMES), "--preset", "bacf", "--stream", "cam-demo",
                          "-e", service.endpoint]) == 0
        out = capsys.readouterr().out
        assert "starting arcf-service" not in out  # no second service
        frames = _accounted(out)
        wait_until(lambda: set(frames) <= set(seen), timeout=30,
                   what="the running service's results on the named stream")
        sub.close()
        assert watcher.status("cam-demo").sessions == []  # the demo stopped its session


def test_the_demo_says_when_no_service_answers(capsys) -> None:
    with pytest.raises(SystemExit, match="no service at"):
        demo.main(["--limit", "2", "-e", f"tcp/127.0.0.1:{free_port()}"])
