"""Service settings: one frozen object, declared once, read from a TOML config file,
``ARCF_SERVICE_*`` variables and command-line flags generated from the declaration."""

from __future__ import annotations

import argparse
import os
import tomllib
import uuid
from collections.abc import Iterable
from dataclasses import MISSING, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, cast

from arcf.client.transport import ZENOH_SHORT_FLAGS

ENV_PREFIX = "ARCF_SERVICE_"



def _about(help: str, choices: tuple[str, ...] | None = None,
           kind: type | None = None) -> dict[str, Any]:
    """A setting's ``metadata``: the help its flag and the docs show, its allowed values, and
    its value type where the default does not say it."""
    return {"help": help, "choices": choices, "kind": kind}


@dataclass(frozen=True)
class ServiceSettings:
    """Every setting of ``arcf-service``, declared once: the command-line flags
    (``--max-stream-fps``), the ``ARCF_SERVICE_*`` environment variables
    (``ARCF_SERVICE_MAX_STREAM_FPS``) and the TOML config file's keys (``max_stream_fps``) are
    all generated from these fields (``add_arguments``, ``from_sources``)."""

    prefix: str = field(default="arcf/v1",
                        metadata=_about("key-expression prefix of the wire contract"))
    mode: str = field(default="router", metadata=_about(
        "Zenoh mode: 'router' embeds a router (no infrastructure needed); 'client' / 'peer' "
        "attach to an existing Zenoh network through --connect",
        choices=("router", "peer", "client")))
    listen: tuple[str, ...] = field(default=("tcp/127.0.0.1:7447",),
                                    metadata=_about("Zenoh listen endpoint (repeatable)"))
    connect: tuple[str, ...] = field(default=(),
                                     metadata=_about("Zenoh connect endpoint (repeatable)"))
    worker_connect: tuple[str, ...] = field(default=(), metadata=_about(
        "where the worker processes connect (repeatable; default: the embedded router's "
        "listen endpoint, else --connect), e.g. a unix-socket endpoint the router also "
        "listens on"))
    worker_listen: tuple[str, ...] = field(default=(), metadata=_about(
        "the direct data path: each worker is a Zenoh peer listening here (repeatable; port "
        "0: a free port per worker) besides its link to the router, and a station that is a "
        "Zenoh peer of the same router links to the worker directly (the router's gossip "
        "tells it where): frames and results no longer cross the router. The --zenoh-config "
        "file's TLS and access control hold on these listeners as on the router's. Empty: "
        "workers are clients of the router"))
    zenoh_config: Path | None = field(default=None, metadata=_about(
        "a Zenoh JSON5 config file applied before the settings above", kind=Path))
    workers: int = field(default_factory=lambda: os.cpu_count() or 1,
                         metadata=_about("worker processes (default: one per core)"))
    spare_workers: int = field(default=0, metadata=_about(
        "worker processes beyond --workers that take no new stream, only one moved off a "
        "worker its streams overload when no move among the others helps (balance_s): "
        "streams are whole, so three streams of 0.55 cores each leave one of two workers "
        "with 1.1 cores; on three processes the kernel shares the two cores among them. "
        "An idle spare costs no CPU"))
    frame_queue: int = field(default=4, metadata=_about(
        "newest frames kept per stream; older ones are dropped (and counted) when a worker "
        "lags. Four absorb a burst of work on a worker (a session's start, a lost target's "
        "search, a stream moving in) without a drop at 30 fps"))
    max_frame_age_ms: float = field(default=200.0, metadata=_about(
        "a queued frame that arrived longer ago than this is dropped (and counted) when its "
        "worker gets to it and a newer frame of its stream waits: a worker that stays behind "
        "drops frames instead of falling behind by frame_queue frame periods at a low frame "
        "rate; 0: off (image streams only: every video unit must be decoded)"))
    video_queue: int = field(default=60, metadata=_about(
        "access units kept per video stream (h264 / h265): each one must be decoded, so the "
        "queue holds what arrives while the worker tracks; beyond it a unit is dropped and "
        "the stream resynchronises at its next keyframe (counted and reported); whatever "
        "the count, a stream's queue holds at most the larger of 32 MiB and two frames of "
        "max_payload"))
    video_history: int = field(default=300, metadata=_about(
        "access units of a video stream's current group of pictures and the one before, "
        "kept from their keyframes on (at most 32 MiB): a box drawn on a picture the worker "
        "has decoded already (the pilot's view lags the stream) is applied to that very "
        "picture, decoded again from its keyframe, and the session catches up to live; a "
        "longer group is not kept, and its box applies to the next picture, saying so. "
        "Also the most a worker asks a "
        "station for of its recent video when it subscribes to a stream (none older than "
        "10 s; the SDK keeps 150). 0: off"))
    video_key: str = field(default="video/{stream}/stream", metadata=_about(
        "where a stream's video also arrives as CDR foxglove.CompressedVideo access units "
        "(BlueOS's MAVLink camera manager's convention); '{stream}' is the stream id; empty: "
        "off"))
    models_dir: Path | None = field(default=None, metadata=_about(
        "the Siamese networks' folder (nanotrack_v2/, vittrack/: arcf.models); default "
        "$ARCF_MODELS, else ../shared/models beside a checkout. Checked at start: a missing "
        "or altered file leaves those presets out, with a warning saying where to get it",
        kind=Path))
    max_payload: int = field(default=8 * 1024 * 1024,
                             metadata=_about("largest accepted frame payload, bytes"))
    max_sessions_per_stream: int = field(default=16,
                                         metadata=_about("most sessions on one stream"))
    max_sessions: int = field(default=256, metadata=_about("most sessions on this instance"))
    max_pixels: int = field(default=4096 * 2160, metadata=_about(
        "largest image in pixels, as its header or parameter set declares it (checked "
        "before a picture is allocated: a decompression bomb costs nothing). The default is "
        "DCI 4K (8.8 MP), the most a drone camera sends; raise it for larger pictures (8K UHD "
        "is 33.2 MP): each one costs its decoding and conversion in full"))
    max_stream_fps: float = field(default=60.0, metadata=_about(
        "most frames/s accepted from one stream (sustained, one second of burst); the excess "
        "is refused and counted, so one flooding station cannot starve the others"))
    max_seq_gap: int = field(default=900, metadata=_about(
        "largest forward jump of a stream's frame numbers taken as lost frames (900: 30 s at "
        "30 fps); a frame further ahead is refused (sequence_jump) unless resync_frames "
        "frames in a row confirm the new numbering"))
    resync_frames: int = field(default=3, metadata=_about(
        "frames in a row, each refused as stale or a jump but following one another, after "
        "which a stream follows their numbering (a restarted station): no single frame can "
        "take a stream's numbering over"))
    session_idle_s: float = field(default=60.0, metadata=_about(
        "a session that produced no result for this long (its stream went quiet, or it waits "
        "for a frame that never comes) ends by itself, with a last 'stopped' result saying "
        "why (session_expired)"))
    stale_after_s: float = field(default=0.8, metadata=_about(
        "a session whose stream delivers no frame for this long says so at once: a result "
        "with status 'stale' (code no_frames, no box), repeated every stale_after_s while it "
        "lasts, so that a station stops following a box that is no longer current; the "
        "session goes on when frames resume (session_idle_s still ends it); 0: off. The "
        "default leaves the notice room to arrive within 1 s of the last frame (it comes "
        "this long after the session's last result, plus tens of ms). Keep it above a few "
        "frame periods of the slowest stream (0.8 s is 8 frames at 10 fps)"))
    client_grace_s: float = field(default=10.0, metadata=_about(
        "a session started with a client_id ends this long after that station's liveliness "
        "token disappears (unless it comes back: a reconnect)"))
    session_budget_ms: float = field(default=250.0, metadata=_about(
        "a session whose frames take longer than this on average (over its last frames) "
        "ends with limit_exceeded: one session must not starve the others on its worker"))
    worker_budget: float = field(default=0.9, metadata=_about(
        "share of its core above which a worker sheds load. Busier than this for 2 s while "
        "a stream's frames waited over 100 ms or were dropped, and with the same stream's "
        "turn (its decoding and tracking, CPU per frame served) costing twice the starved "
        "one's both seconds, it ends that stream's costliest sessions until its turn fits, "
        "or all its sessions when its decoding costs more than any of them (limit_exceeded, "
        "counted in arcf_sessions_shed_total). Among equals nothing is shed: each stream "
        "keeps its newest frames and drops the rest (counted); a stream alone on its worker "
        "may use all of it. 0: off"))
    state_file: Path | None = field(default=None, metadata=_about(
        "keep the session registry, each session with its last box, in this file (written "
        "at most every 0.5 s while it changes, and at exit); started again with the same "
        "file, the instance resumes those sessions from their last box (status resumed), "
        "after a SIGTERM as after a SIGKILL. Without it a lone instance that restarts "
        "starts empty (a fleet's other instances take its sessions over either way)",
        kind=Path))
    last_box_period_ms: int = field(default=200, metadata=_about(
        "each worker puts the last box of its sessions on <prefix>/boxes/<instance>/<worker> "
        "at most this often (when one changed): the box another instance resumes a session "
        "from when this one dies, at most this old plus a frame. Instances follow these, not "
        "every result: what each receives grows with the sessions, not with their frame "
        "rate"))
    balance_s: float = field(default=2.0, metadata=_about(
        "every this many seconds, the pool moves one stream from its busiest worker to a "
        "less busy one if that lowers the busiest worker's load (the CPU each stream used, "
        "smoothed over a few seconds) by at least balance_min_gain and that worker is above "
        "balance_busy_above; a moved stream is not moved again for 10 s. Its sessions' state "
        "moves with it (the next result is the one the old worker would have given); video "
        "streams and the Siamese presets' stay. New streams go to the least loaded worker "
        "either way. 0: streams stay where they were placed"))
    balance_min_gain: float = field(default=0.1, metadata=_about(
        "cores a move must take off the busiest worker (balance_s); negative: a stream moves "
        "every round even when it does not help (for testing the moves)"))
    balance_busy_above: float = field(default=0.5, metadata=_about(
        "cores below which the busiest worker is left alone (balance_s): its frames do not "
        "wait; negative: always balanced"))
    worker_max_rss_mb: int = field(default=2048, metadata=_about(
        "a worker whose resident memory passes this (checked every second) resets its video "
        "decoders, each stream resuming at its next keyframe (decode_error, resync cause "
        "'memory'), and returns its freed memory to the system; 0: off"))
    session_control: str = field(default="owner", metadata=_about(
        "who may stop or re-initialise a session: 'owner', the holder of its control token "
        "(sent to the station that started it, in the start's ack); 'open', any station "
        "that may query the control key (the deployment's ACL is then the only rule)",
        choices=("owner", "open")))
    quarantine_after: int = field(default=2, metadata=_about(
        "a stream whose frames were being processed when this many worker processes died "
        "(a crash in a decoder, the out-of-memory killer) within quarantine_s is quarantined: "
        "its sessions end instead of resuming, and starts on it are refused (code "
        "quarantined) for quarantine_s; 0: never"))
    quarantine_s: float = field(default=600.0, metadata=_about(
        "the window in which a stream's worker crashes count, and how long its quarantine "
        "lasts"))
    metrics_host: str = field(default="127.0.0.1",
                              metadata=_about("Prometheus endpoint address"))
    metrics_port: int = field(default=9464, metadata=_about(
        "Prometheus endpoint port (0: any free port, negative: disabled)"))
    lease_ms: int = field(default=10000,
                          metadata=_about("Zenoh lease, ms: how fast a hung peer is noticed"))
    worker_start_s: float = field(default=120.0, metadata=_about(
        "seconds start-up waits for every worker to be ready (a worker loads the tracker's "
        "compiled kernels, or compiles them where no cache exists: about a minute, every "
        "worker at once); past this the service exits with an error instead of serving"))
    instance_id: str = field(default_factory=lambda: uuid.uuid4().hex[:8], metadata=_about(
        "this instance's id among several (default: random)"))

    def __post_init__(self) -> None:
        if self.mode not in ("router", "peer", "client"):
            raise ValueError(f"mode must be router, peer or client, got {self.mode!r}")
        if self.mode == "client" and not self.connect:
            raise ValueError("client mode needs at least one connect endpoint")
        if self.workers < 1:
            raise ValueError("workers must be >= 1")
        if not self.worker_start_s > 0:
            raise ValueError("worker_start_s must be > 0")
        if self.frame_queue < 1:
            raise ValueError("frame_queue must be >= 1")
        if self.max_frame_age_ms < 0:
            raise ValueError("max_frame_age_ms must be >= 0 (0: off)")
        if self.video_queue < 1:
            raise ValueError("video_queue must be >= 1")
        if self.video_history < 0:
            raise ValueError("video_history must be >= 0")
        if self.video_key and (self.video_key.count("{stream}") != 1
                               or any(c in self.video_key.replace("{stream}", "")
                                      for c in "*$?#{}")
                               or self.video_key.strip("/") != self.video_key):
            raise ValueError("video_key must be a key expression without wildcards holding "
                             f"'{{stream}}' once, got {self.video_key!r}")
        if self.max_payload < 1024:
            raise ValueError("max_payload must be at least 1024 bytes")
        if self.max_sessions < 1 or self.max_sessions_per_stream < 1:
            raise ValueError("max_sessions and max_sessions_per_stream must be >= 1")
        if self.max_pixels < 1:
            raise ValueError("max_pixels must be >= 1")
        if not self.max_stream_fps > 0:
            raise ValueError("max_stream_fps must be > 0")
        if not (self.session_idle_s > 0 and self.client_grace_s >= 0
                and self.session_budget_ms > 0):
            raise ValueError("session_idle_s and session_budget_ms must be > 0, "
                             "client_grace_s >= 0")
        if self.session_control not in ("owner", "open"):
            raise ValueError(f"session_control must be owner or open, got "
                             f"{self.session_control!r}")
        if self.quarantine_after < 0 or not self.quarantine_s > 0:
            raise ValueError("quarantine_after must be >= 0 (0: never) and quarantine_s > 0")
        if self.last_box_period_ms < 1:
            raise ValueError("last_box_period_ms must be >= 1")
        if self.worker_max_rss_mb < 0:
            raise ValueError("worker_max_rss_mb must be >= 0 (0: off)")
        if self.balance_s < 0:
            raise ValueError(f"balance_s must be >= 0 (0: off), got {self.balance_s!r}")
        if not 0 <= self.worker_budget <= 1:
            raise ValueError(f"worker_budget must be within [0, 1] (0: off), got "
                             f"{self.worker_budget!r}")
        if not (self.stale_after_s == 0 or 0.1 <= self.stale_after_s <= 3600):
            # below 0.1 s a stream's own frame interval (and its jitter) would look stale
            raise ValueError("stale_after_s must be 0 (off) or within [0.1, 3600] s, got "
                             f"{self.stale_after_s!r}")
        if self.max_seq_gap < 1 or self.resync_frames < 2:
            raise ValueError("max_seq_gap must be >= 1 and resync_frames >= 2")
        if any(c in self.prefix for c in "*$?#") or self.prefix.strip("/") != self.prefix:
            raise ValueError(f"invalid key-expression prefix {self.prefix!r}")

    @property
    def transport_limit(self) -> int:
        """The largest message the service's Zenoh sessions reassemble: four times
        ``max_payload`` (at least 32 MiB), so that every frame a station can deliver up to there
        arrives and is refused with ``oversized_payload``, counted and reported; beyond it the
        transport discards the message (bounding the memory a hostile sender can claim)."""
        return max(4 * self.max_payload, 32 << 20)

    @property
    def worker_endpoints(self) -> tuple[str, ...]:
        """Where workers connect: ``worker_connect``, else the embedded router's listen
        endpoints, else ``connect``."""
        if self.worker_connect:
            return self.worker_connect
        if self.mode == "router":
            return tuple(e.replace("0.0.0.0", "127.0.0.1") for e in self.listen)
        return self.connect or self.listen

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None, **overrides: object) -> ServiceSettings:
        """Settings from ``ARCF_SERVICE_<FIELD>`` variables (lists comma-separated), then
        ``overrides`` (None: not given)."""
        return cls.from_sources(None, env, **overrides)

    @classmethod
    def from_sources(cls, config: str | os.PathLike[str] | None = None,
                     env: dict[str, str] | None = None, **overrides: object
                     ) -> ServiceSettings:
        """Defaults, then the TOML ``config`` file, then ``ARCF_SERVICE_*`` variables, then
        ``overrides`` (the flags; None: not given): each later source wins. Unknown keys and
        values of the wrong type are refused with ``ValueError``."""
        env = dict(os.environ if env is None else env)
        values: dict[str, object] = {}
        if config is not None:
            try:
                with open(config, "rb") as f:
                    table = tomllib.load(f)
            except (OSError, tomllib.TOMLDecodeError) as exc:
                raise ValueError(f"config file {config}: {exc}") from exc
            unknown = sorted(set(table) - set(_FIELDS))
            if unknown:
                raise ValueError(f"config file {config}: unknown settings {unknown}; valid: "
                                 f"{sorted(_FIELDS)}")
            for name, value in table.items():
                values[name] = _convert(name, value)
        for name in _FIELDS:
            raw = env.get(ENV_PREFIX + name.upper())
            if raw is not None:
                values[name] = _convert(name, raw)
        for name, value in overrides.items():
            if name not in _FIELDS:
                raise ValueError(f"unknown setting {name!r}")
            if value is not None:
                values[name] = _convert(name, value)
        return replace(cls(), **values)  # type: ignore[arg-type]


_FIELDS = {f.name: f for f in fields(ServiceSettings)}


def _kind(name: str) -> type:
    """A setting's value type: declared (``kind``), else its default's."""
    f = _FIELDS[name]
    if f.metadata.get("kind") is not None:
        return f.metadata["kind"]
    default = f.default if f.default_factory is MISSING else f.default_factory()
    return type(default)


def _convert(name: str, value: object) -> object:
    """A value from a flag, a variable (text) or the config file, as the setting's type."""
    kind = _kind(name)
    try:
        if kind is tuple:
            if isinstance(value, str):
                return tuple(v.strip() for v in value.split(",") if v.strip())
            return tuple(str(v) for v in cast(Iterable[object], value))
        if kind is bool:
            if isinstance(value, str):
                return value.strip().lower() in ("1", "true", "yes", "on")
            return bool(value)
        if kind in (int, float) and isinstance(value, bool):
            raise TypeError("a number, not true / false")
        return kind(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"setting {name}: cannot use {value!r} ({exc})") from exc


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """One ``--flag`` per setting (repeatable for lists; the Zenoh ones also with the short
    names of zenoh-python's examples, ``-m -e -l -c``), and ``--settings FILE``."""
    parser.add_argument("--settings", type=Path, metavar="FILE",
                        help="a TOML file of settings (keys as the flags, with underscores); "
                        "ARCF_SERVICE_* variables and flags override it")
    for name, f in _FIELDS.items():
        flags = [ZENOH_SHORT_FLAGS[name]] if name in ZENOH_SHORT_FLAGS else []
        flags.append("--" + name.replace("_", "-"))
        kind = _kind(name)
        text = f.metadata.get("help") or None
        if kind is tuple:
            parser.add_argument(*flags, dest=name, action="append", help=text)
        elif kind is bool:
            parser.add_argument(*flags, dest=name, action=argparse.BooleanOptionalAction,
                                help=text)
        else:
            parser.add_argument(*flags, dest=name, type=kind, choices=f.metadata.get("choices"),
                                help=text)


def from_arguments(args: argparse.Namespace, env: dict[str, str] | None = None
                   ) -> ServiceSettings:
    """The settings of parsed ``add_arguments`` flags, over the config file and variables."""
    flags = {name: getattr(args, name, None) for name in _FIELDS}
    return ServiceSettings.from_sources(config=args.settings, env=env, **flags)
