"""Service settings: one frozen object, from command-line flags and ``ARCF_SERVICE_*`` variables."""

from __future__ import annotations

import os
import uuid
from dataclasses import dataclass, field, replace
from pathlib import Path

ENV_PREFIX = "ARCF_SERVICE_"


@dataclass(frozen=True)
class ServiceSettings:
    #: Key-expression prefix of the wire contract.
    prefix: str = "arcf/v1"
    #: Zenoh mode of the main process: "router" embeds a router (no infrastructure needed);
    #: "client"/"peer" attach to an existing Zenoh network through ``connect``.
    mode: str = "router"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    #: A Zenoh JSON5 config file applied before the settings above.
    zenoh_config: Path | None = None
    #: Worker processes (default: one per core).
    workers: int = field(default_factory=lambda: os.cpu_count() or 1)
    #: Newest frames kept per stream; older ones are dropped (and counted) when a worker lags.
    frame_queue: int = 2
    #: Largest accepted frame payload, bytes.
    max_payload: int = 8 * 1024 * 1024
    #: Largest number of sessions on one stream.
    max_sessions_per_stream: int = 16
    #: Largest number of sessions on this instance.
    max_sessions: int = 256
    #: Largest image, in pixels, as declared by its header (checked before decoding: a
    #: decompression bomb is refused without allocating anything). 8K UHD is 33.2 MP.
    max_pixels: int = 40_000_000
    #: Most frames per second accepted from one stream (sustained; one second of burst); the
    #: excess is refused and counted, so one flooding station cannot starve the others.
    max_stream_fps: float = 60.0
    metrics_host: str = "127.0.0.1"
    #: Prometheus endpoint port (0: pick a free port; negative: disabled).
    metrics_port: int = 9464
    #: Zenoh lease (ms): how fast a hung peer is noticed.
    lease_ms: int = 10000
    #: Seconds start-up waits for every worker to be ready. A worker loads the tracker's
    #: compiled kernels first, or compiles them where no cache exists (~11 s, longer on a
    #: loaded machine); past this the service exits with an error instead of serving.
    worker_start_s: float = 120.0
    instance_id: str = field(default_factory=lambda: uuid.uuid4().hex[:8])

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
        if self.max_payload < 1024:
            raise ValueError("max_payload must be at least 1024 bytes")
        if self.max_sessions < 1 or self.max_sessions_per_stream < 1:
            raise ValueError("max_sessions and max_sessions_per_stream must be >= 1")
        if self.max_pixels < 1:
            raise ValueError("max_pixels must be >= 1")
        if not self.max_stream_fps > 0:
            raise ValueError("max_stream_fps must be > 0")
        if any(c in self.prefix for c in "*$?#") or self.prefix.strip("/") != self.prefix:
            raise ValueError(f"invalid key-expression prefix {self.prefix!r}")

    @property
    def worker_endpoints(self) -> tuple[str, ...]:
        """Where workers connect: the embedded router's listen endpoints, else ``connect``."""
        if self.mode == "router":
            return tuple(e.replace("0.0.0.0", "127.0.0.1") for e in self.listen)
        return self.connect or self.listen

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None, **overrides: object) -> ServiceSettings:
        """Settings from ``ARCF_SERVICE_<FIELD>`` variables (lists comma-separated)."""
        env = dict(os.environ if env is None else env)
        values: dict[str, object] = {}
        base = cls()
        for name in base.__dataclass_fields__:
            raw = env.get(ENV_PREFIX + name.upper())
            if raw is None:
                continue
            current = getattr(base, name)
            if isinstance(current, tuple):
                values[name] = tuple(v.strip() for v in raw.split(",") if v.strip())
            elif isinstance(current, bool):
                values[name] = raw.lower() in ("1", "true", "yes")
            elif isinstance(current, int):
                values[name] = int(raw)
            elif isinstance(current, float):
                values[name] = float(raw)
            elif name == "zenoh_config":
                values[name] = Path(raw)
            else:
                values[name] = raw
        values.update({k: v for k, v in overrides.items() if v is not None})
        return replace(base, **values)  # type: ignore[arg-type]
