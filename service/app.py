"""``arcf-service``: the launcher. Embedded Zenoh router, control plane, workers, metrics.

    arcf-service                         # router on tcp/127.0.0.1:7447, one worker per core
    arcf-service --mode client --connect tcp/router.example:7447 --workers 4

Shuts down cleanly on SIGTERM/SIGINT: workers close their Zenoh sessions and exit, then the
control plane and the router close. No process is left behind.
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing as mp
import multiprocessing.connection as mp_connection
import os
import signal
import sys
import threading
import time
from typing import Any

from arcf import __version__
from arcf.client.transport import LOG_FORMAT

from . import multiproc
from .settings import ServiceSettings, add_arguments, from_arguments
from .supervision import InFlight, death_cause

log = logging.getLogger(__name__)


class Service:
    """The running service (main process side). ``start()``, then ``wait()`` or ``close()``."""

    def __init__(self, settings: ServiceSettings) -> None:
        self.settings = settings
        self._stop = threading.Event()
        self.metrics_url = ""
        #: seconds the start-up's own start took (``_serve_a_start``)
        self.ready_s = 0.0

    def start(self) -> Service:
        s = self.settings
        self.metrics_dir = multiproc.prepare()  # before prometheus_client is imported
        import zenoh
        from prometheus_client import start_http_server

        from arcf.client.transport import open_session
        from arcf.schemas import KeySpace

        from . import metrics
        from .cluster import Cluster
        from .control import ControlPlane
        from .links import RouterLinks
        from .statefile import StateFile
        from .untracked import UntrackedNotices
        from .worker import worker_main

        self.keys = KeySpace(s.prefix)
        self.session = open_session(s.mode, listen=s.listen if s.mode != "client" else (),
                                    connect=s.connect,
                                    config_file=s.zenoh_config, lease_ms=s.lease_ms,
                                    max_message_size=s.transport_limit)
        self.http = None
        if s.metrics_port >= 0:
            self.http, _ = start_http_server(s.metrics_port, addr=s.metrics_host,
                                             registry=metrics.aggregate_registry())
            self.metrics_url = f"http://{s.metrics_host}:{self.http.server_port}/metrics"
        ctx = mp.get_context("spawn")  # never fork a process holding a Zenoh session
        self.worker_stop = ctx.Event()
        processes = s.workers + s.spare_workers
        self.queues = [ctx.Queue() for _ in range(processes)]
        self.responses = ctx.Queue()
        #: per worker, the stream whose frame it is processing (read when it dies)
        self.inflight = [InFlight(ctx) for _ in range(processes)]
        self.procs = [ctx.Process(target=worker_main, args=(k, s, self.queues[k],
                                                              self.responses, self.worker_stop,
                                                              self.inflight[k]),
                                  name=f"arcf-worker-{k}") for k in range(processes)]
        for p in self.procs:
            p.start()
        session = self.session
        self.cluster = Cluster(
            self.session, self.keys, s.instance_id,
            # a client reaches the others only through a router; a router or a peer may not
            linked=(lambda: any(session.info.routers_zid())) if s.mode == "client" else None,
            state=StateFile(s.state_file) if s.state_file is not None else None)
        self.control = ControlPlane(s, self.queues, __version__, responses=self.responses,
                                    cluster=self.cluster)
        self.cluster.on_change = self.control.rebalance
        self.cluster.start()  # the others' sessions are known before this instance joins
        self.queryable = self.session.declare_queryable(self.keys.control(),
                                                        self.control.handle_query)

        def client_token(sample: Any) -> None:
            client = str(sample.key_expr).rsplit("/", 1)[-1]
            self.control.client_token(client, sample.kind == zenoh.SampleKind.PUT)

        # stations' liveliness tokens (optional in the contract): their sessions end when
        # the station is gone (see ControlPlane.client_token)
        self.clients = self.session.liveliness().declare_subscriber(
            self.keys.all_client_tokens(), client_token, history=True)

        def worker_token(sample: Any) -> None:
            if sample.kind == zenoh.SampleKind.PUT:  # a replacement is ready for sessions
                worker = str(sample.key_expr).rsplit("/", 1)[-1]
                if worker.isdigit():
                    self.control.worker_ready(int(worker))

        self.worker_tokens = self.session.liveliness().declare_subscriber(
            self.keys.workers_of_instance(s.instance_id), worker_token)
        # Frames of streams nobody tracks: counted, and answered with a rate-limited error.
        # Through the embedded router, by every frame's key; else by the stations' publisher
        # tokens (a subscription to every frame would draw the direct path's frames, or in a
        # fleet every instance's, through this process)
        self.untracked = UntrackedNotices(
            self.session, self.keys, self.control.tracked_streams, metrics,
            mine=self.cluster.mine)
        if s.mode == "router" and not s.worker_listen:
            self.untracked.watch_frames()
        else:
            self.untracked.watch_publishers()
        # a client's link to its router (a router or a peer may have none, rightly)
        self.links = RouterLinks(self.session, metrics) if s.mode == "client" else None
        self._wait_for_workers(self.settings.worker_start_s)
        self.cluster.join()  # now others may hand streams to us, and we take ours
        self.ready_s = self._serve_a_start(self.settings.worker_start_s)
        metrics.READY.set(1)
        return self

    def _serve_a_start(self, timeout: float) -> float:
        """Start a session through the service's own control key, as a station does (on a
        stream only this instance answers for, ``_ready-<instance>-0``), end it, and return
        how long the start took. Ready is announced only after it: a worker's token says it
        runs, not that a start reaches it through the router, the control plane and back."""
        from arcf.client import ServiceError, TrackingClient

        from .control import readiness_stream

        s = self.settings
        client = TrackingClient(session=self.session, prefix=s.prefix, tie_sessions=False)
        stream = readiness_stream(s.instance_id)
        t0 = time.monotonic()
        while True:
            try:
                ack = client.start(stream, (1.0, 1.0, 16.0, 16.0), preset="bacf",
                                   timeout=min(5.0, max(timeout, 0.1)))
                served = time.monotonic() - t0
                log.debug("start-up: session %s served", ack.session_id)
                break
            except (TimeoutError, ServiceError) as exc:
                if time.monotonic() - t0 > timeout:
                    raise RuntimeError(f"no start served within {timeout:.0f} s: {exc}") from exc
                log.info("start-up: a start was not served yet (%s); again", exc)
                time.sleep(0.2)
        self.control.end_readiness_checks()
        client.close()
        return served

    def _wait_for_workers(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        key = self.keys.workers_of_instance(self.settings.instance_id)
        while time.monotonic() < deadline:
            alive = [r for r in self.session.liveliness().get(key, timeout=1.0) if r.ok]
            if len(alive) >= len(self.procs):
                return
            if any(not p.is_alive() for p in self.procs):
                raise RuntimeError("a worker process died during start-up")
            time.sleep(0.05)
        raise RuntimeError(f"workers not ready after {timeout:.0f} s")

    def request_stop(self, *_: Any) -> None:
        self._stop.set()

    def wait(self) -> None:
        from . import metrics

        memory = metrics.MEMORY.labels(process="main")
        while not self._stop.is_set():
            # a worker's end wakes this at once (its sentinel), a stop request within 0.2 s
            mp_connection.wait([p.sentinel for p in self.procs], timeout=0.2)
            memory.set(metrics.resident_bytes())
            self.untracked.tick()
            if self.links is not None:
                self.links.poll()
            for k, p in enumerate(self.procs):
                if not p.is_alive() and not self._stop.is_set():
                    self._replace_worker(k)

    def _replace_worker(self, k: int) -> None:
        """Supervision: a dead worker is replaced at once. Its sessions (their trackers lived in
        that process) resume on a live worker from their last published box, like sessions of
        a dead instance (on the replacement once it is ready, when no other worker lives);
        their streams are told on their error keys, and the first result after says
        ``resumed``. The stream whose frame the worker was processing gets a strike; at
        ``quarantine_after`` strikes its sessions end instead (code ``quarantined``)."""
        import zenoh

        from arcf.schemas import ErrorCode, ErrorMessage, encode

        from . import metrics
        from .worker import worker_main

        old = self.procs[k]
        cause = death_cause(old.exitcode)
        culprit = self.inflight[k].read()
        self.inflight[k].clear()
        log.error("worker %d died (%s%s); starting a replacement", k, cause,
                  f", on a frame of stream {culprit}" if culprit else ", between frames")
        metrics.ERRORS.labels(kind="worker_died").inc()
        metrics.WORKER_DEATHS.labels(cause=cause).inc()
        if old.pid:
            metrics.mark_dead(old.pid)
        ctx = mp.get_context("spawn")
        queue = ctx.Queue()  # the old one may be locked by the killed process
        lost, quarantined = self.control.worker_replaced(k, queue, culprit)
        self.queues[k] = queue
        for rec in lost:
            if quarantined and rec.stream_id == culprit:
                self.cluster.withdraw(rec.session_id)  # ended, not resumed
                code = ErrorCode.QUARANTINED
                message = (f"worker {k} died ({cause}) on a frame of stream {culprit}: "
                           f"{self.control.strikes.after} workers died on its frames within "
                           f"{self.settings.quarantine_s:g} s, so session {rec.session_id} "
                           f"ended and starts on the stream are refused for "
                           f"{self.settings.quarantine_s:g} s")
            else:
                code = ErrorCode.INTERNAL
                message = (f"worker {k} died ({cause}); session {rec.session_id} resumes "
                           "from its last published box")
            self.session.put(
                self.keys.errors(rec.stream_id),
                encode(ErrorMessage(code=code, stream_id=rec.stream_id,
                                    session_id=rec.session_id, message=message)),
                congestion_control=zenoh.CongestionControl.DROP)
        self.cluster.request_rebalance()  # the registry still has them: they start again
        # started after the sessions are on their way to a live worker: its start-up (imports,
        # kernels) must not delay them
        proc = ctx.Process(target=worker_main, args=(k, self.settings, queue, self.responses,
                                                     self.worker_stop, self.inflight[k]),
                           name=f"arcf-worker-{k}")
        proc.start()
        self.procs[k] = proc

    def close(self) -> None:
        from . import metrics

        # Stop intake, then leave the cluster at once: the survivors take this instance's
        # streams over (the registry entries stay, so the sessions resume there) while the
        # workers finish the frames they hold and send each session's final status.
        metrics.READY.set(0)
        self.worker_stop.set()
        self.cluster.close()
        for p in self.procs:
            p.join(timeout=5)
            if p.is_alive():
                p.terminate()
                p.join(timeout=2)
            if p.pid:
                metrics.mark_dead(p.pid)
        self.responses.put(None)  # ends the control plane's pump thread...
        self.control.pump_thread.join(timeout=5)  # ...before its queue is closed under it
        self.control.background.shutdown(wait=False, cancel_futures=True)
        for q in [*self.queues, self.responses]:
            q.close()
            q.join_thread()
        self.untracked.close()
        self.worker_tokens.undeclare()
        self.queryable.undeclare()
        self.session.close()
        if self.http is not None:
            self.http.shutdown()


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="arcf-service", description=__doc__.splitlines()[0])
    add_arguments(ap)  # one flag per setting, from its declaration
    ap.add_argument("--version", action="version", version=f"arcf-service {__version__}")
    return ap


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    args = build_parser().parse_args(argv)
    try:
        settings = from_arguments(args)
    except ValueError as exc:
        raise SystemExit(f"arcf-service: {exc}") from exc
    service = Service(settings)
    signal.signal(signal.SIGTERM, service.request_stop)
    signal.signal(signal.SIGINT, service.request_stop)
    try:
        service.start()
    except Exception as exc:
        # Without this, the threads already started (cluster, control plane) would keep a
        # service that never became ready alive, silently: exit with the reason instead.
        log.error("start-up failed: %s", exc)
        try:
            service.close()
        except Exception:  # partly started: close what can be closed
            log.debug("close after a failed start-up", exc_info=True)
        print(f"arcf-service: start-up failed: {exc}", file=sys.stderr, flush=True)
        os._exit(1)  # no thread left behind may keep a service that never became ready alive
    endpoints = ", ".join(settings.listen if settings.mode == "router" else settings.connect)
    print(f"arcf-service ready: zenoh {settings.mode} {endpoints}, prefix {settings.prefix}, "
          f"{settings.workers} workers, metrics {service.metrics_url or 'off'} (a start served "
          f"in {1e3 * service.ready_s:.0f} ms)", flush=True)
    try:
        service.wait()
    finally:
        service.close()
        print("arcf-service stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
