"""Prometheus metrics shared by the main process and the workers (multiprocess mode).

Names follow Prometheus conventions (base units, ``_total`` counters); no label carries a stream
or session id, so cardinality stays bounded whatever the traffic.
"""

from __future__ import annotations

import os

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, multiprocess

LATENCY_BUCKETS = (0.005, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0)
STEP_BUCKETS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.2, 0.5, 1.0)

END_TO_END = Histogram(
    "arcf_end_to_end_latency_seconds",
    "Capture timestamp to result published (includes transport and queueing)",
    buckets=LATENCY_BUCKETS,
)
DECODE = Histogram("arcf_decode_seconds", "Image decoding time per frame", buckets=STEP_BUCKETS)
QUEUE_WAIT = Histogram("arcf_queue_wait_seconds", "Time a frame waited in its stream's queue "
                       "before its worker took it (wall time)", buckets=STEP_BUCKETS)
TRACK = Histogram("arcf_track_seconds", "Tracker time per session and frame", buckets=STEP_BUCKETS)
FRAMES_RECEIVED = Counter("arcf_frames_received_total", "Frames taken from the network by workers")
FRAMES_PROCESSED = Counter("arcf_frames_processed_total", "Frames decoded and tracked")
FRAMES_DECODED = Counter(
    "arcf_frames_decoded_total", "Pictures decoded (JPEG) or converted (video) for tracking, "
    "whole or only where the trackers read them", ["extent"])
FRAMES_DROPPED = Counter(
    "arcf_frames_dropped_total", "Frames skipped: gaps in a stream's sequence numbers"
)
VIDEO_RESYNCS = Counter(
    "arcf_video_resyncs_total",
    "Video streams resynchronised at their next keyframe, by cause (gap, corrupt, oversized, "
    "memory: the worker passed worker_max_rss_mb)",
    ["cause"],
)
VIDEO_REPLAYED = Counter(
    "arcf_video_replayed_pictures_total",
    "Video pictures decoded again from their group's keyframe for a box drawn on a picture "
    "the worker had passed, and tracked by that session to catch up to live",
)
SHED = Counter(
    "arcf_sessions_shed_total",
    "Sessions a worker ended because it was over worker_budget while another stream's frames "
    "waited or were dropped: the heaviest, by what cost most (tracking, or decoding its stream)",
    ["cause"],
)
RESULTS = Counter("arcf_results_published_total", "Result messages published")
STALE = Counter(
    "arcf_sessions_stale_total",
    "Sessions that went stale: their stream delivered no frame for stale_after_s (counted once "
    "per episode; the notice repeated while it lasts is not counted)",
)
ERRORS = Counter("arcf_errors_total", "Errors by kind", ["kind"])
STAGE_CPU = Counter(
    "arcf_stage_cpu_seconds_total",
    "Workers' CPU seconds by stage of a frame's path (receive, parse, decode, convert, track, "
    "publish, metrics), added once a second",
    ["stage"],
)
CONTROL = Counter("arcf_control_requests_total", "Control requests by type and outcome",
                  ["type", "outcome"])
TAKEOVERS = Counter("arcf_sessions_taken_over_total",
                    "Sessions this instance took over from another (failover or rebalance)")
STREAM_MOVES = Counter(
    "arcf_stream_moves_total",
    "Streams moved from this instance's busiest worker to a less busy one, by the CPU each "
    "stream measured (balance_s), with their sessions' state: moved, or refused (it stayed)",
    ["outcome"])
HANDOVERS = Counter("arcf_sessions_handed_over_total",
                    "Sessions this instance handed to another (an instance joined)")
WORKER_DEATHS = Counter(
    "arcf_worker_deaths_total",
    "Worker processes that died and were replaced, by cause (SIGSEGV, SIGKILL: also the "
    "kernel's out-of-memory killer, SIGABRT, exit <code>)", ["cause"])
CRASH_STRIKES = Counter(
    "arcf_stream_crash_strikes_total",
    "Worker deaths that happened while a frame of a stream was being processed (a strike "
    "against that stream); quarantine_after of them within quarantine_s quarantine it")
QUARANTINES = Counter("arcf_streams_quarantined_total",
                      "Streams quarantined: they were in flight when workers died too often")
ROUTERS = Gauge("arcf_zenoh_routers", "Zenoh routers the instance's main session is linked "
                "to (0: cut off from the fleet's routers)", multiprocess_mode="livesum")
ROUTER_RECONNECTS = Counter(
    "arcf_router_reconnects_total",
    "Links to a Zenoh router the instance made again after losing one (its router died or "
    "was cut off, and Zenoh linked it to another endpoint of --connect, or the same one back)")
STREAMS = Gauge("arcf_active_streams", "Streams with at least one session",
                multiprocess_mode="livesum")
SESSIONS = Gauge("arcf_active_sessions", "Tracking sessions", multiprocess_mode="livesum")
READY = Gauge("arcf_ready", "1 once the instance has served a start of its own through its "
              "control key (what its ready line and health check mean)",
              multiprocess_mode="max")
BUSY = Gauge("arcf_worker_busy_ratio", "Share of wall time a worker spent working",
             ["worker"], multiprocess_mode="liveall")

MEMORY = Gauge("arcf_process_resident_bytes",
               "Resident memory of each process of the service (main, worker-<k>)",
               ["process"], multiprocess_mode="liveall")


def resident_bytes() -> int:
    """This process's resident set, from /proc (0 where there is no /proc)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return 0


_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def aggregate_registry() -> CollectorRegistry:
    """A registry that sums the metric files of every process (for the HTTP endpoint)."""
    registry = CollectorRegistry()
    multiprocess.MultiProcessCollector(registry)
    return registry


def mark_dead(pid: int) -> None:
    """Drop a finished worker's live gauges."""
    multiprocess.mark_process_dead(pid)
