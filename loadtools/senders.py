"""Real video senders on loopback, for the ingest's tests and benchmarks.

* :class:`VideoSender`: a camera's encoder output sent as a camera or a companion computer
  sends it, by FFmpeg's muxers through PyAV: RTP (H.264 or H.265, dynamic payload type 96, no
  SDP needed by a receiver that knows the convention) or MPEG-TS over UDP, paced at the
  stream's frame rate, in a thread. Stopping it and starting a new one is a camera that
  restarts (a new RTP sequence and timestamp origin, a new SSRC).
* :class:`UdpRelay`: a relay between sender and receiver that loses the datagrams a rule
  picks (a radio link's burst of losses), counting them.
* :class:`RtspServer`: Debian's GStreamer RTSP server (``gir1.2-gst-rtsp-server-1.0``, run by
  the system's Python, which has PyGObject) serving an MPEG-TS file as a camera's
  ``rtsp://127.0.0.1:PORT/cam`` (RTP H.264, parameter sets in-band each second).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from fractions import Fraction
from pathlib import Path
from typing import cast

import av

from arcf.client.media.encodings import codec_of

#: the RTP clock of every video payload format (RFC 6184, RFC 7798)
RTP_CLOCK = 90_000


def write_video_file(units: Sequence[bytes], path: Path, size: tuple[int, int],
                     codec: str = "h264", fps: int = 30) -> Path:
    """Mux Annex B access units into a file (MP4, MKV, TS: by ``path``'s suffix), unchanged
    (MP4 and MKV store them length-prefixed with the parameter sets in the configuration:
    FFmpeg converts)."""
    with av.open(str(path), "w") as out:
        stream = cast(av.VideoStream, out.add_stream(codec_of(codec).decoder_name, rate=fps))
        stream.width, stream.height = size
        for i, unit in enumerate(units):
            out.mux(_packet(unit, stream, i, fps, codec))
    return path


def _packet(unit: bytes, stream: av.VideoStream, i: int, fps: int, codec: str) -> av.Packet:
    packet = av.Packet(unit)
    packet.stream = stream
    packet.time_base = Fraction(1, fps)
    packet.pts = packet.dts = i
    packet.is_keyframe = codec_of(codec).is_keyframe(unit)
    return packet


class VideoSender:
    """Send access units to ``url`` with FFmpeg's ``fmt`` muxer (``rtp`` or ``mpegts``), one
    every 1 / ``fps`` s, ``repeat`` times over (presentation times go on increasing), in a
    thread. ``sent`` counts the units handed to the muxer."""

    def __init__(self, units: Sequence[bytes], url: str, fmt: str, size: tuple[int, int], *,
                 codec: str = "h264", fps: int = 30, repeat: int = 1) -> None:
        if fmt not in ("rtp", "mpegts"):
            raise ValueError(f"fmt must be rtp or mpegts, got {fmt!r}")
        self.units, self.url, self.fmt, self.size = list(units), url, fmt, size
        self.codec, self.fps, self.repeat = codec, fps, repeat
        self.sent = 0
        self.error: Exception | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"sender-{fmt}", daemon=True)

    def start(self) -> VideoSender:
        self._thread.start()
        return self

    def _run(self) -> None:
        try:
            with av.open(self.url, "w", format=self.fmt) as out:
                stream = cast(av.VideoStream,
                              out.add_stream(codec_of(self.codec).decoder_name, rate=self.fps))
                stream.width, stream.height = self.size
                t0 = time.monotonic()
                for k in range(self.repeat * len(self.units)):
                    due = t0 + k / self.fps
                    if self._stop.wait(max(0.0, due - time.monotonic())):
                        return
                    out.mux(_packet(self.units[k % len(self.units)], stream, k, self.fps,
                                    self.codec))
                    self.sent += 1
        except Exception as exc:  # reported to the test, which asserts on it
            self.error = exc

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        self._thread.join(timeout)


def _udp_pair() -> tuple[socket.socket, socket.socket]:
    """Two UDP sockets bound on loopback to an even port and the next (RTP and RTCP)."""
    for _ in range(200):
        first = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        first.bind(("127.0.0.1", 0))
        port = first.getsockname()[1]
        if port % 2 == 0 and port < 65534:
            second = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                second.bind(("127.0.0.1", port + 1))
                return first, second
            except OSError:
                second.close()
        first.close()
    raise OSError("no free pair of UDP ports")


def free_rtp_port() -> int:
    """An even loopback UDP port whose next is free too, for a receiver of RTP and RTCP."""
    first, second = _udp_pair()
    port = first.getsockname()[1]
    first.close()
    second.close()
    return int(port)


class UdpRelay:
    """Forward UDP datagrams from ``127.0.0.1:port`` (and ``port + 1``, RTCP) to ``target``
    (and ``target + 1``), losing those for which ``lose(i)`` is true, ``i`` counting the
    datagrams of the first port from 0. ``forwarded`` and ``lost`` count them."""

    def __init__(self, target: int, lose: Callable[[int], bool]) -> None:
        self.target, self.lose = target, lose
        self.forwarded = self.lost = 0
        self._stop = threading.Event()
        self._socks = list(_udp_pair())
        for sock in self._socks:
            sock.settimeout(0.2)
        self.port = self._socks[0].getsockname()[1]
        self._out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._threads = [threading.Thread(target=self._pump, args=(k,), daemon=True)
                         for k in range(2)]
        for t in self._threads:
            t.start()

    def _pump(self, k: int) -> None:
        i = 0
        while not self._stop.is_set():
            try:
                data = self._socks[k].recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if k == 0:
                if self.lose(i):
                    self.lost += 1
                    i += 1
                    continue
                i += 1
                self.forwarded += 1
            self._out.sendto(data, ("127.0.0.1", self.target + k))

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(2)
        for s in (*self._socks, self._out):
            s.close()


#: the RTSP server, run by the system's Python (PyGObject and GStreamer from Debian)
_RTSP_SERVER = r"""
import sys, gi
gi.require_version("Gst", "1.0")
gi.require_version("GstRtspServer", "1.0")
from gi.repository import Gst, GstRtspServer, GLib
Gst.init(None)
port, path = sys.argv[1], sys.argv[2]
server = GstRtspServer.RTSPServer()
server.set_address("127.0.0.1")
server.set_service(port)
factory = GstRtspServer.RTSPMediaFactory()
factory.set_launch(f"( filesrc location={path} ! tsdemux ! h264parse ! "
                   "rtph264pay name=pay0 pt=96 config-interval=1 )")
server.get_mount_points().add_factory("/cam", factory)
if server.attach(None) == 0:
    sys.exit("cannot listen on port " + port)
print("ready", flush=True)
GLib.MainLoop().run()
"""

#: the system's Python, which Debian's PyGObject belongs to
SYSTEM_PYTHON = "/usr/bin/python3"


def rtsp_server_problem() -> str | None:
    """Why :class:`RtspServer` cannot run here (None: it can)."""
    if shutil.which(SYSTEM_PYTHON) is None:
        return f"no {SYSTEM_PYTHON}"
    probe = subprocess.run(
        [SYSTEM_PYTHON, "-c", "import gi; gi.require_version('GstRtspServer', '1.0'); "
         "gi.require_version('Gst', '1.0'); from gi.repository import Gst, GstRtspServer; "
         "Gst.init(None); assert Gst.ElementFactory.find('tsdemux') and "
         "Gst.ElementFactory.find('h264parse') and Gst.ElementFactory.find('rtph264pay')"],
        capture_output=True, text=True, timeout=60)
    if probe.returncode != 0:
        return ("GStreamer's RTSP server is not installed (Debian: gir1.2-gst-rtsp-server-1.0 "
                "gstreamer1.0-plugins-good gstreamer1.0-plugins-bad python3-gi): "
                + probe.stderr.strip()[-200:])
    return None


class RtspServer:
    """GStreamer's RTSP server on ``127.0.0.1:port`` serving ``ts_file`` (H.264 in MPEG-TS) at
    ``url``; each client that connects gets the file from its start, at its frame rate."""

    def __init__(self, ts_file: Path, port: int) -> None:
        self.port = port
        self.url = f"rtsp://127.0.0.1:{port}/cam"
        self.proc = subprocess.Popen([SYSTEM_PYTHON, "-c", _RTSP_SERVER, str(port),
                                      str(ts_file)], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()  # blocks until it listens, or exits
        if line.strip() != "ready":
            self.stop()
            raise RuntimeError(f"the RTSP server did not start: {self.proc.stderr.read()[-500:]}"
                               if self.proc.stderr else "the RTSP server did not start")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        for f in (self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()

    def __enter__(self) -> RtspServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
