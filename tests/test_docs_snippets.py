"""The docs' code examples are files (``docs/snippets/*.py``) that the pages include with
pymdownx.snippets: every include names a file, every snippet is included by a page and checked
here, and each runs in its own interpreter, within a deadline, exits 0 and prints what its page
says it prints. Those that talk to a service get one started here on loopback, named by
``ARCF_ENDPOINT``, as a reader's would be by its address."""

from __future__ import annotations

import ast
import math
import os
import re
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from arcf.data import data_root

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
SNIPPETS = DOCS / "snippets"
#: ``--8<-- "docs/snippets/x.py"``, pymdownx.snippets' include (paths from the repository root)
INCLUDE = re.compile(r'^\s*--8<--\s+"([^"]+)"\s*$', re.M)
#: what one snippet may take, on a loaded 2-core machine (most take a few seconds)
DEADLINE_S = 300.0

needs_data = pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                reason="needs ../shared/data")

#: snippet file name -> the test that runs it (filled by ``@checks``)
CHECKED: dict[str, str] = {}


def checks(*names: str, processes: bool = True
           ) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """A test of snippets: it needs the shared data, starts processes (``integration``)
    unless told otherwise, and records which snippets it runs, so that a snippet nobody runs
    fails the suite."""
    def mark(test: Callable[..., None]) -> Callable[..., None]:
        for name in names:
            CHECKED[name] = test.__name__
        test = needs_data(test)
        return pytest.mark.integration(test) if processes else test
    return mark


def pages() -> list[Path]:
    return sorted(p for p in DOCS.rglob("*.md") if SNIPPETS not in p.parents)


def includes() -> dict[Path, list[str]]:
    """Every page's snippet includes, as written."""
    return {page: INCLUDE.findall(page.read_text(encoding="utf-8")) for page in pages()}


def run(name: str, *args: str, env: dict[str, str] | None = None,
        timeout: float = DEADLINE_S) -> str:
    """Run ``docs/snippets/<name>`` as a reader would (``python docs/snippets/<name>`` from
    the repository root); its standard output, once it exited 0 within ``timeout``."""
    proc = subprocess.run([sys.executable, str(SNIPPETS / name), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})
    assert proc.returncode == 0, f"{name} exited {proc.returncode}:\n{proc.stderr[-3000:]}"
    return proc.stdout


def _box(text: str) -> tuple[float, float, float, float]:
    x, y, w, h = ast.literal_eval(text)
    return float(x), float(y), float(w), float(h)


def _iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


# ------------------------------------------------------------------ the files and the pages

def test_every_include_names_a_snippet_file() -> None:
    found = includes()
    assert any(found.values()), "no page includes a snippet"
    for page, paths in found.items():
        for path in paths:
            target = ROOT / path
            assert target.is_file(), f"{page.relative_to(ROOT)} includes {path}: no such file"
            assert target.parent == SNIPPETS, f"{page.relative_to(ROOT)}: {path} is not a snippet"


def test_every_snippet_is_included_by_a_page_and_run_here() -> None:
    included = {Path(path).name for paths in includes().values() for path in paths}
    files = {p.name for p in SNIPPETS.glob("*.py")}
    assert files, "docs/snippets/ is empty"
    assert not files - included, f"snippets no page includes: {sorted(files - included)}"
    assert not files - set(CHECKED), f"snippets no test runs: {sorted(files - set(CHECKED))}"
    assert not set(CHECKED) - files, f"tests of missing snippets: {sorted(set(CHECKED) - files)}"


def test_pages_show_no_python_example_that_is_not_a_snippet() -> None:
    """A fenced Python block on a page is an include, so that every example shown runs."""
    fence = re.compile(r"^( *)```python\n(.*?)^\1```", re.M | re.S)
    for page in pages():
        for _, body in fence.findall(page.read_text(encoding="utf-8")):
            assert re.fullmatch(r'--8<--\s+"[^"]+"', body.strip()), (
                f"{page.relative_to(ROOT)}: a Python example not in docs/snippets/:\n{body}")


# ------------------------------------------------------------------ the library

@checks("first_track.py")
def test_first_track_follows_the_boat() -> None:
    lines = run("first_track.py").splitlines()
    assert len(lines) == 29, lines  # frames 1..29 after the init frame
    rows = [re.fullmatch(r"(\d+) (\(.*\)) (\w+) ([\d.]+) ([\d.]+)", line) for line in lines]
    assert all(rows), lines
    assert [int(r[1]) for r in rows if r] == list(range(1, 30))
    last = rows[-1]
    assert last is not None and last[3] == "tracking" and float(last[4]) > 0.5
    gt = (data_root() / "published_results/UAV123_10fps/groundtruth/boat1.txt").read_text()
    truth = tuple(float(v) for v in gt.splitlines()[29].split(","))
    assert _iou(_box(last[2]), truth) > 0.5, (last[2], truth)


@checks("run_sequence.py")
def test_a_sequence_is_run_and_scored() -> None:
    out = run("run_sequence.py")
    m = re.search(r"MountainBike6: (\d+) frames at (\d+) FPS, P@20 ([\d.]+), AUC ([\d.]+)", out)
    assert m, out
    assert int(m[1]) == 81 and int(m[2]) > 0
    assert float(m[3]) > 0.8 and float(m[4]) > 0.5, out  # it follows the bike


@checks("score_published.py")
def test_the_published_boxes_give_the_papers_figures() -> None:
    out = run("score_published.py")
    assert "precision@20 0.666  AUC 0.473  (123 sequences, toolkit convention)" in out, out
    m = re.search(r"(\d+) sequences with frames here: (.*)", out)
    assert m and int(m[1]) == len(m[2].split(", ")) and "boat1" in m[2], out


@checks("release_compatible.py")
def test_release_mode_gives_the_release_boxes() -> None:
    out = run("release_compatible.py")
    m = re.search(r"(\d+) frames, mean centre distance to the release: ([\d.]+) px", out)
    assert m and int(m[1]) == 60 and float(m[2]) <= 0.5, out


@checks("add_preset.py")
def test_a_candidate_preset_runs_beside_its_family() -> None:
    out = run("add_preset.py")
    assert "family: arcf" in out, out
    scores = dict(re.findall(r"^(arcf-h(?:-3s)?): P@20 ([\d.]+), AUC [\d.]+, \d+ FPS$", out,
                             re.M))
    assert set(scores) == {"arcf-h", "arcf-h-3s"}, out
    assert all(float(p) > 0.9 for p in scores.values()), out


@checks("encodings.py", processes=False)
def test_every_encoding_of_the_wire_is_walked() -> None:
    from arcf.schemas import Encoding

    out = run("encodings.py")
    lines = dict(line.split(": ", 1) for line in out.splitlines())
    assert set(lines) == {e.value for e in Encoding}, out
    for name, line in lines.items():
        if Encoding(name).is_video:
            assert line.startswith("video, FFmpeg ") and "keyframe NAL types [" in line, line
        else:
            assert "size (1280, 720)" in line, line
            assert line.endswith("(720, 1280)" if name == "gray8" else "(720, 1280, 3)"), line


# ------------------------------------------------------------------ through a service

@pytest.fixture(scope="module")
def service() -> Iterator[dict[str, str]]:
    """One ``arcf-service`` on a free loopback port for the module's snippets: the
    environment that names it to them."""
    pytest.importorskip("zenoh")
    from arcf.loadtools.procs import ServiceProcess

    with ServiceProcess(workers=1) as svc:
        yield {"ARCF_ENDPOINT": svc.endpoint}


class Replay:
    """``replay_stream.py`` publishing a stream in the background, as a camera would."""

    def __init__(self, env: dict[str, str], stream: str, frames: int) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, str(SNIPPETS / "replay_stream.py"), stream, str(frames)],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env={**os.environ, **env})

    def finish(self, timeout: float = DEADLINE_S) -> str:
        out, err = self.proc.communicate(timeout=timeout)
        assert self.proc.returncode == 0, err[-3000:]
        return out

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


@checks("first_session.py")
def test_a_first_session_answers_every_frame(service: dict[str, str]) -> None:
    lines = run("first_session.py", env=service).splitlines()
    assert len(lines) == 20, lines
    fields = [line.split(" ", 2) for line in lines]
    assert [int(f[0]) for f in fields] == list(range(20)), lines
    assert fields[0][1] == "initialized", lines
    assert all(f[1] == "tracking" for f in fields[1:]), lines


@checks("direct_station.py")
def test_a_peer_station_links_to_the_worker() -> None:
    pytest.importorskip("zenoh")
    from arcf.loadtools.procs import ServiceProcess

    with ServiceProcess("--worker-listen", "tcp/127.0.0.1:0", workers=1) as svc:
        lines = run("direct_station.py", env={"ARCF_ENDPOINT": svc.endpoint}).splitlines()
    assert lines[0] == "linked to 1 worker(s)", lines
    assert [line.split(" ") for line in lines[1:]] == [
        [str(k), "initialized" if k == 0 else "tracking"] for k in range(10)], lines


@checks("fleet.py")
def test_a_fleet_accounts_for_every_frame(service: dict[str, str]) -> None:
    out = run("fleet.py", env=service)
    m = re.fullmatch(r"([\d.]+) (\{.*\}) (\{.*\})\n", out)
    assert m, out
    accounting = ast.literal_eval(m[3])
    assert math.isfinite(float(m[1])) and "p99" in ast.literal_eval(m[2]), out  # reported
    assert accounting["sessions"] == 3 and accounting["results"] > 0, accounting
    assert accounting["unaccounted"] == 0 and accounting["out_of_order"] == 0, accounting


def _wait_for_stream(service: dict[str, str], stream: str) -> None:
    """Until the replay's stream is announced on the service's network (its publisher's
    liveliness token), with a deadline."""
    from arcf.client import TrackingClient
    from arcf.loadtools.waiting import wait_until

    with TrackingClient(connect=[service["ARCF_ENDPOINT"]]) as client:
        wait_until(lambda: stream in client.streams(), timeout=60,
                   what=f"stream {stream!r} published")


@checks("replay_stream.py", "track_stream.py")
def test_a_station_tracks_a_stream_another_publishes(service: dict[str, str]) -> None:
    replay = Replay(service, "gimbal", 80)  # 8 s at 10 fps
    try:
        _wait_for_stream(service, "gimbal")  # the camera is on before the station starts
        lines = run("track_stream.py", "gimbal", env=service).splitlines()
        assert "80 frames published on 'gimbal'" in replay.finish()
    finally:
        replay.stop()
    assert len(lines) == 30, lines
    statuses = [line.split(" ")[1] for line in lines]
    assert statuses[0] == "initialized" and set(statuses[1:]) == {"tracking"}, lines
    seqs = [int(line.split(" ")[0]) for line in lines]
    assert seqs == sorted(seqs) and seqs[0] > 0, seqs  # from a frame after the start


@checks("mavsdk_station.py")
def test_mavsdk_tracks_through_arcf_mavlink_as_the_page_shows(service: dict[str, str]) -> None:
    """docs/mavlink.md's MAVSDK station against ``arcf-mavlink`` started as that page says,
    on a replayed stream: the camera, its video URI, a rectangle, ten statuses, a stop."""
    pytest.importorskip("mavsdk")
    from arcf.loadtools.procs import free_port

    port = free_port()
    uri = "rtsp://127.0.0.1:8554/cam1"
    replay = Replay(service, "cam1", 600)  # bounded: 60 s at 10 fps, stopped when done
    adapter = subprocess.Popen(
        [str(Path(sys.executable).parent / "arcf-mavlink"), "-e", service["ARCF_ENDPOINT"],
         "--camera", "cam1", "--video", f"cam1={uri}",
         "--mavlink", f"udpout:127.0.0.1:{port}"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_stream(service, "cam1")
        # boat1's boat on its first frames, in shares of the 1280 x 720 picture
        lines = run("mavsdk_station.py", f"udpin://127.0.0.1:{port}",
                    "0.306,0.455,0.427,0.898").splitlines()
    finally:
        replay.stop()
        adapter.terminate()
        _, err = adapter.communicate(timeout=30)
    assert lines[0] == "camera 100 ARCF tracker cam1 1280x720", (lines, err[-2000:])
    assert lines[1] == f"video {uri}", lines
    assert lines[2] == "track_rectangle SUCCESS", lines
    statuses = [line.split(" ") for line in lines[3:13]]
    assert all(s[0] == "status" and s[1] in ("ACTIVE", "ERROR", "ACTIVE|COASTING")
               for s in statuses), lines
    boxed = [s for s in statuses if "-" not in s[2:]]
    assert boxed, lines  # the track's rectangle reached MAVSDK
    for s in boxed:  # a rectangle inside the picture, left of right and above bottom
        x0, y0, x1, y1 = (float(v) for v in s[2:])
        assert 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1, s
    assert lines[13:] == ["track_stop SUCCESS", "status IDLE"], lines


@checks("adapter.py")
def test_an_adapter_speaks_in_shares_of_the_picture(service: dict[str, str]) -> None:
    replay = Replay(service, "cam1", 60)
    try:
        _wait_for_stream(service, "cam1")
        out = run("adapter.py", "cam1", "393,328,155,319", "20", env=service)
        replay.finish()
    finally:
        replay.stop()
    header, *rows = out.splitlines()
    assert header == "frame,status,state,cx,cy,w,h" and len(rows) == 20, out
    with_box = [row.split(",") for row in rows if row.split(",")[2]]
    assert len(with_box) >= 15, out  # the picture's size is known from the first frame on
    for _, _, state, *shares in with_box:
        assert state in ("tracking", "coasting", "lost")
        assert all(0.0 < float(v) < 1.0 for v in shares), shares
