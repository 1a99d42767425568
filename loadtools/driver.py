"""The stream driver: a fleet of simulated drones publishing real frames to the service.

A :class:`Clip` is what one drone replays (a real sequence's JPEG bytes, passed through as they
are, and the box its sessions start from). A :class:`Pacing` says when a stream publishes its
next frame. A :class:`Fleet` adds and removes streams while the service runs, each with its own
thread and tracking sessions, and records everything in a :class:`~arcf.loadtools.ledger.Ledger`.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .ledger import Ledger, Received, StreamRecord

#: spreads any number of phases evenly over a period (k * GOLDEN mod 1)
GOLDEN = 0.6180339887498949


@dataclass(frozen=True)
class Clip:
    """The frames one simulated drone replays, cycled, and the box its sessions start from."""

    name: str
    box: tuple[float, float, float, float]
    frames: tuple[bytes, ...]
    #: ground truth of the sequence's frames, in publication order (frame i: row i mod len);
    #: None for a forth-and-back clip, which is not scored
    groundtruth: np.ndarray | None = None
    #: the frames' wire encoding: ``jpeg`` (the datasets' files, or as the SDK sends them:
    #: :meth:`as_sent`), or ``h264`` / ``h265`` access units (:meth:`as_video`)
    encoding: str = "jpeg"

    @classmethod
    def of(cls, sequence: Any, *, limit: int = 0, palindrome: bool = False) -> Clip:
        """The first ``limit`` frames (all with 0) of an :mod:`arcf.eval` sequence. A
        ``palindrome`` clip plays them forth and back (0 1 ... n-1 n-2 ... 1), so the target
        moves continuously and a session never has to be re-initialised at a wrap."""
        paths = sequence.frames[:limit] if limit else sequence.frames
        data = [p.read_bytes() for p in paths]
        x, y, w, h = (float(v) for v in sequence.init_box)
        if palindrome:
            return cls(sequence.name, (x, y, w, h), tuple(data + data[-2:0:-1]))
        return cls(sequence.name, (x, y, w, h), tuple(data),
                   np.asarray(sequence.groundtruth[: len(data)], dtype=float))

    def __len__(self) -> int:
        return len(self.frames)

    def as_sent(self, quality: int = 90) -> Clip:
        """The same clip as the client SDK sends pictures (``encode_image``): JPEG at
        ``quality`` with restart intervals that let a worker decode only around the target
        (the datasets' own files have none)."""
        from arcf.client.media.encodings import encode_image
        from arcf.client.media.images import decode_compressed

        return replace(self, frames=tuple(encode_image(decode_compressed(f), "jpeg", quality)
                                          for f in self.frames))

    def as_video(self, codec: str = "h264", fps: int = 30) -> Clip:
        """The same clip as a drone camera's video: one access unit per frame, a keyframe
        every 30 (the first included, so a cycled clip restarts on a keyframe)."""
        from arcf.client.media.images import decode_compressed

        from .video import encode_video

        units = encode_video((decode_compressed(f) for f in self.frames), codec, fps=fps)
        return replace(self, frames=tuple(units), encoding=codec)


@dataclass(frozen=True)
class Pacing:
    """When a stream publishes its next frame.

    - **fixed rate** (``fps`` > 0): a camera. Independent drones' cameras are not
      synchronised, so stream k's frames fall at phase ``k * GOLDEN mod 1`` of the period (even
      for any number of streams, and for streams added later); ``aligned`` puts every stream's
      frames at the same instants, the worst case of a synchronised fleet.
    - **as fast as possible** (``fps`` 0, ``in_flight`` 0): a flood, for overload tests.
    - **closed loop** (``in_flight`` > 0): frame i is sent only once frame i - in_flight has
      a result from every session of the stream (or after ``wait_s``). With ``fps`` 0 this
      saturates the workers without a single drop, unless it outruns the service's
      per-stream rate limit (``max_stream_fps``, 60 by default: a fast worker answers a small
      target in under 10 ms, and a frame refused there has no result); ``in_flight`` 1 is
      **lock-step**, one frame at a time, so latency has no queueing in it.
    """

    fps: float = 10.0
    in_flight: int = 0
    aligned: bool = False
    wait_s: float = 2.0

    @classmethod
    def fixed_rate(cls, fps: float, *, aligned: bool = False) -> Pacing:
        return cls(fps=fps, aligned=aligned)

    @classmethod
    def closed_loop(cls, in_flight: int = 1, *, fps: float = 0.0) -> Pacing:
        return cls(fps=fps, in_flight=in_flight)

    @classmethod
    def lock_step(cls, fps: float = 30.0) -> Pacing:
        """One frame at a time, each once the previous one is answered, and no faster than
        ``fps`` (a camera's rate, half the service's default ``max_stream_fps``: a replay
        that outran the limit would have frames refused, and every refused frame would wait
        ``wait_s`` for an answer that never comes). ``fps`` 0: as fast as the answers come,
        for a service whose limit is raised."""
        return cls(fps=fps, in_flight=1, wait_s=30.0)

    def __post_init__(self) -> None:
        if self.fps < 0 or self.in_flight < 0 or self.wait_s < 0:
            raise ValueError(f"negative pacing: {self}")

    def phase(self, k: int) -> float:
        """Offset of stream k's frames within the period (seconds)."""
        if self.aligned or self.fps <= 0:
            return 0.0
        return ((k * GOLDEN) % 1.0) / self.fps

    def schedule(self, k: int, epoch: float, start: float) -> Callable[[int], float]:
        """When stream k publishes its frame i (monotonic s), given the fleet's ``epoch`` and
        the earliest time it may start: fixed-rate frames fall on the stream's phase of the
        period counted from the epoch, from the first such instant at or after ``start``;
        otherwise every frame is due at once (the closed loop waits by itself)."""
        if self.fps <= 0:
            return lambda i: start
        period = 1.0 / self.fps
        phase = epoch + self.phase(k)
        first_slot = math.ceil((start - phase) / period - 1e-9)
        return lambda i: phase + (first_slot + i) * period


@dataclass
class SimulatedStream:
    """One simulated drone: its clip, sessions, publishing thread and ledger record."""

    name: str
    index: int
    clip: Clip
    record: StreamRecord
    #: frames to publish (None: until removed)
    limit: int | None = None
    reinit_on_wrap: bool = False
    acks: list[Any] = field(default_factory=list)
    stop: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None
    subscription: Any = None

    @property
    def sessions(self) -> list[str]:
        return self.record.sessions

    @property
    def sent(self) -> int:
        return len(self.record.sent)

    def publishing(self) -> bool:
        return self.thread is not None and self.thread.is_alive()


class Fleet:
    """Streams of real frames that can be added and removed while the service runs.

    Every stream gets ``sessions`` tracking sessions started on its clip's box at frame 0;
    stream ``k`` replays clip ``k mod len(clips)``. Results go to the fleet's ledger (and to
    ``on_result``, if given, e.g. to print them). Streams added with ``hold`` wait for
    :meth:`release`, so that a run can start every session first and all streams together.
    """

    def __init__(self, client: Any, clips: Sequence[Clip], *, preset: str = "arcf-h",
                 pacing: Pacing | None = None, ledger: Ledger | None = None,
                 prefix: str = "stream",
                 on_result: Callable[[SimulatedStream, Received], None] | None = None) -> None:
        if not clips:
            raise ValueError("a fleet needs at least one clip")
        self.client, self.clips, self.preset = client, list(clips), preset
        self.pacing = pacing or Pacing()
        self.ledger = ledger or Ledger()
        self.prefix, self.on_result = prefix, on_result
        self.live: list[SimulatedStream] = []
        self.ended: list[SimulatedStream] = []
        self.sessions_started = 0
        self.sessions_stopped = 0
        #: sessions whose stop request failed (e.g. during a takeover), with the error
        self.stop_errors: list[tuple[str, str]] = []
        self._count = 0
        self._epoch = time.monotonic()  # every stream's frame instants count from here
        self._released = threading.Event()
        self._released_at = 0.0

    @property
    def fps(self) -> float:
        return self.pacing.fps

    def add(self, n: int = 1, *, sessions: int | Sequence[str] = 1,
            names: Sequence[str] | None = None, clip: Clip | None = None,
            frames: int | None = None, reinit_on_wrap: bool = False, delay: float = 0.0,
            stagger: float = 0.0, hold: bool = False,
            session_id: Callable[[str, int], str] | None = None
            ) -> list[SimulatedStream]:
        """Start ``n`` streams (or one per name of ``names``: chosen ids, e.g. to reuse one), each
        with ``sessions`` sessions of the fleet's preset (or one per preset listed) and
        replaying ``clip`` (default: the fleet's clips in turn), publishing ``frames`` frames
        (None: until removed); the j-th of them starts ``delay + j * stagger`` s from now, or
        from :meth:`release` with ``hold``, at its next frame instant. With
        ``reinit_on_wrap`` the sessions are re-initialised on the clip's box each time it
        starts over (the one frame where that box is right). ``session_id(stream, j)`` names
        the sessions (default: the service's). If a session cannot be started, the stream's
        other sessions are stopped again and the error is raised."""
        out = []
        for j in range(len(names) if names is not None else n):
            k = self._count
            self._count += 1
            replayed = clip if clip is not None else self.clips[k % len(self.clips)]
            st_name = names[j] if names is not None else f"{self.prefix}-{k}-{replayed.name}"
            st = SimulatedStream(st_name, k, replayed, self.ledger.open(st_name), limit=frames,
                                 reinit_on_wrap=reinit_on_wrap)

            def deliver(result: Any, st: SimulatedStream = st) -> None:
                got = st.record.on_result(result)
                if got is not None and self.on_result is not None:
                    self.on_result(st, got)

            st.subscription = self.client.results(st.name, callback=deliver)
            presets = [self.preset] * sessions if isinstance(sessions, int) else sessions
            try:
                for s, preset in enumerate(presets):
                    ack = self.client.start(
                        st.name, replayed.box, preset=preset, frame_seq=0,
                        session_id=session_id(st.name, s) if session_id else None)
                    st.acks.append(ack)
                    st.record.add_session(ack.session_id)
                    self.sessions_started += 1
            except BaseException:
                self._stop_sessions(st)
                raise
            st.thread = threading.Thread(target=self._publish,
                                         args=(st, delay + j * stagger, hold),
                                         daemon=True, name=f"publish-{st.name}")
            st.thread.start()
            self.live.append(st)
            out.append(st)
        return out

    def release(self) -> float:
        """Let the streams added with ``hold`` start; the time they start from."""
        self._released_at = time.monotonic()
        self._released.set()
        return self._released_at

    def _publish(self, st: SimulatedStream, delay: float, hold: bool) -> None:
        pacing, rec = self.pacing, st.record
        if hold:
            while not self._released.wait(0.05):
                if st.stop.is_set():
                    return
        base = self._released_at if hold else time.monotonic()
        due = pacing.schedule(st.index, self._epoch, base + delay)
        n_frames = len(st.clip)
        i = 0
        while st.limit is None or i < st.limit:
            wait_s = due(i) - time.monotonic()
            if st.stop.wait(max(wait_s, 0.0)):
                return
            if st.reinit_on_wrap and i and i % n_frames == 0:
                for sid in st.sessions:  # a new box on this frame: the tracker starts over
                    self.client.reinit(sid, st.clip.box, frame_seq=i)
            if pacing.in_flight and i >= pacing.in_flight:  # closed loop: frame i - in_flight
                wanted, count = i - pacing.in_flight, len(st.sessions)
                def answered(w: int = wanted, c: int = count) -> bool:
                    return rec.answered(w) >= c or st.stop.is_set()

                rec.wait(answered, pacing.wait_s)
            if st.stop.is_set():
                return
            self.client.publish_frame(st.name, data=st.clip.frames[i % n_frames],
                                      encoding=st.clip.encoding, seq=i)
            rec.on_sent(i)
            i += 1

    def wait_published(self, timeout: float) -> bool:
        """Wait until every stream with a frame count has published them (False on timeout;
        streams without a count are not waited for)."""
        deadline = time.monotonic() + timeout
        bounded = [st for st in self.live if st.limit is not None and st.thread is not None]
        for st in bounded:
            assert st.thread is not None
            st.thread.join(max(0.0, deadline - time.monotonic()))
        return not any(st.publishing() for st in bounded)

    def settle(self, timeout: float = 10.0) -> bool:
        """Wait until every session has answered its stream's last frame sent (the frames
        still queued when publishing stopped); False if some never did within ``timeout``."""
        deadline = time.monotonic() + timeout
        for st in self.live:
            rec = st.record
            if st.sent:
                last, count = rec.sent[-1][0], len(st.sessions)
                def drained(r: StreamRecord = rec, s: int = last, c: int = count) -> bool:
                    return r.answered(s) >= c

                if not rec.wait(drained, deadline - time.monotonic()):
                    return False
        return True

    def pause(self, streams: list[SimulatedStream] | None = None) -> None:
        """Stop publishing (sessions stay); a closed loop waiting for an answer stops at
        once."""
        chosen = list(self.live) if streams is None else streams
        for st in chosen:
            st.stop.set()
            st.record.wake()
        for st in chosen:
            if st.thread is not None:
                st.thread.join(timeout=10.0)  # at most one reinit request (5 s) in progress

    def remove(self, n: int = 1, *, streams: list[SimulatedStream] | None = None) -> None:
        """Stop ``streams`` (default: the ``n`` newest): publishing stops, then the sessions.
        A session whose stop fails is recorded in ``stop_errors``; the rest are stopped."""
        chosen = streams if streams is not None else self.live[-n:] if n else []
        self.pause(chosen)
        for st in chosen:
            self._stop_sessions(st)
            self.live.remove(st)
            self.ended.append(st)

    def _stop_sessions(self, st: SimulatedStream) -> None:
        """Stop the stream's sessions, except those the service already ended (their last
        result, ``stopped``, came: a stop would only be refused as ``unknown_session``)."""
        with st.record.cond:
            ended = {r.session_id for r in st.record.ended}
        try:
            for sid in st.sessions:
                if sid in ended:
                    continue
                try:
                    self.client.stop(sid)
                    self.sessions_stopped += 1
                except Exception as exc:  # e.g. a takeover in progress: report, go on
                    self.stop_errors.append((sid, f"{type(exc).__name__}: {exc}"))
        finally:
            st.subscription.close()

    def close(self) -> None:
        self.remove(streams=list(self.live))

    def __enter__(self) -> Fleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ measurements
    def streams(self) -> list[SimulatedStream]:
        return self.ended + self.live

    def window(self, t0: float, t1: float, streams: list[SimulatedStream] | None = None
               ) -> dict[str, Any]:
        """:meth:`Ledger.window` of these streams (default: all, past and present)."""
        chosen = self.streams() if streams is None else streams
        return self.ledger.window(t0, t1, [st.record for st in chosen])


def balanced_streams(instances: Sequence[str], per_instance: int) -> list[str]:
    """Stream ids ``cam-<k>``, ``per_instance`` owned by each of ``instances`` by the
    cluster's rendezvous hashing: a failover run knows which streams each instance owns."""
    from arcf.service.cluster import owner

    names: list[str] = []
    for k in range(100 * per_instance * len(instances)):
        name = f"cam-{k}"
        if sum(owner(n, instances) == owner(name, instances) for n in names) < per_instance:
            names.append(name)
        if len(names) == per_instance * len(instances):
            return names
    raise ValueError(f"no {per_instance} stream ids for each of {list(instances)}")


def failover_fleet(client: Any, clip: Clip, names: Sequence[str], *, preset: str, fps: float,
                   frames: int) -> Fleet:
    """The streams failover runs watch: one per name (the names decide which instance owns
    which stream, so a run that keeps them is comparable), each with one session
    ``s-<stream>``, all publishing ``frames`` frames of the clip at ``fps`` at the same
    instants."""
    fleet = Fleet(client, [clip], preset=preset, pacing=Pacing.fixed_rate(fps, aligned=True))
    fleet.add(names=names, frames=frames, session_id=lambda stream, _: f"s-{stream}")
    return fleet
