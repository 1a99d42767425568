"""Scale-out: instances of the service on one Zenoh network share the streams.

Zenoh is the fabric; nothing here is a broker. Three Zenoh mechanisms carry it:

* **Membership**: each instance's main process holds a liveliness token
  ``<prefix>/instances/<id>``. Every instance watches those tokens, so every instance knows the
  live set. A killed instance's token vanishes when its connection closes; a hung one's when the
  Zenoh lease expires (``lease_ms``).
* **Ownership**: a stream belongs to the instance with the highest rendezvous weight for it
  among the live set (:func:`owner`). Every instance computes the same answer from the same
  set without talking, and a change of the set moves only the streams of the instance that
  left, or a fair share to the one that joined.
* **Session registry**: the owner of a session puts its spec (stream, preset, overrides, box)
  on ``<prefix>/registry/<session>`` and deletes it when the session stops; every instance
  subscribes. Each worker puts the last box of every session it runs on
  ``<prefix>/boxes/<instance>/<worker>`` at a bounded rate (``last_box_period_ms``), and every
  instance follows those: what an instance receives to take over grows with the sessions, not
  with the frames they track (it followed every result before). When an owner dies, the new
  owner resumes its sessions from the last box it heard of on the next frame.
  A joining instance asks the others for their registry (a query on ``<prefix>/registry/*``)
  before it announces itself. With a state file (``service/statefile.py``) the registry is
  also kept on disk, and a restarted instance resumes what it ran.
"""

from __future__ import annotations

import hashlib
import logging
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from typing import Any

from arcf.schemas import (
    MAX_BOX_COORD,
    KeySpace,
    LastBoxes,
    SchemaError,
    SessionSpec,
    decode,
    encode,
)

from .statefile import SAVE_PERIOD_S, StateFile

log = logging.getLogger(__name__)

#: boxes of not-yet-registered sessions kept at most (a worker's readiness check's session is
#: never registered: its box waits here until newer ones push it out)
EARLY_BOXES = 4096
#: how often a rebalance cut off from every router looks whether it is linked again
LINK_POLL_S = 0.01


def weight(key: str, member: str | int) -> int:
    return int.from_bytes(
        hashlib.blake2b(f"{key}\x00{member}".encode(), digest_size=8).digest(), "big")


def owner(key: str, members: Iterable[Any]) -> Any:
    """Rendezvous (highest-random-weight) hashing: the member that owns ``key``.

    Every process computes the same owner from the same member set, and removing or adding a
    member moves only the keys it owned (or, for a new member, the keys it now wins)."""
    return max(members, key=lambda m: weight(key, m))


def usable_box(box: Any) -> bool:
    """A box a session can be resumed from: finite, positive size, within the contract's
    coordinate range (a collapsed track can report a zero-height box; such a box is not kept,
    and the session resumes from the last usable one)."""
    return (len(box) == 4 and all(math.isfinite(v) for v in box) and box[2] > 0 and box[3] > 0
            and max(abs(v) for v in box) <= MAX_BOX_COORD)


class Cluster:
    """Membership, the replicated session registry and the last box of every session.

    ``on_change`` is called (from a thread of its own, never inside a Zenoh callback) whenever
    the live set or the registry changed, so the control plane can take over or hand over.
    """

    def __init__(self, session: Any, keys: KeySpace, instance_id: str,
                 on_change: Callable[[], None] | None = None,
                 linked: Callable[[], bool] | None = None,
                 state: StateFile | None = None) -> None:
        self.session = session
        #: the registry on disk (None: none): merged at start, written as it changes
        self.state = state
        #: bumped by every change of the registry or of a last box; what the file has
        self._version = 0
        self._saved = 0
        self._save_lock = threading.Lock()  # the saver thread's write and close()'s
        #: whether the instance is linked to a router now (None: it is one). An instance cut
        #: off from its router sees every other instance's token vanish at once, and Zenoh
        #: links it to another router of its list milliseconds later, the tokens coming back:
        #: it acts on the membership once linked, not on what the lost link made it see
        self.linked = linked
        self.keys = keys
        self.instance_id = instance_id
        self.on_change = on_change
        self.lock = threading.Lock()
        self.members: set[str] = set()
        self.specs: dict[str, SessionSpec] = {}
        #: session -> (frame_seq, box) of its last result with a box
        self.last: dict[str, tuple[int, tuple[float, float, float, float]]] = {}
        #: boxes of sessions whose spec has not arrived yet (a worker's first box can overtake
        #: its owner's registry put); the oldest go first past ``EARLY_BOXES``
        self.early: OrderedDict[str, tuple[int, tuple[float, float, float, float]]] = \
            OrderedDict()
        self.joined = False
        self._changed = threading.Event()
        #: another instance appeared (joined, or came back from a partition): registries are
        #: merged before the next rebalance. What one side of a partition put or deleted
        #: never reached the other (Zenoh does not replay publications), so a session one
        #: side ended, its station out of sight, may still run on the other, its station
        #: in sight: the union is kept, and a station really gone ends its sessions again
        #: after client_grace_s.
        self._resync = threading.Event()
        self._closing = False
        self._token: Any = None
        self._subs: list[Any] = []
        self._queryable: Any = None
        self._thread = threading.Thread(target=self._notify_loop, name="arcf-cluster",
                                        daemon=True)
        self._saver = threading.Thread(target=self._save_loop, name="arcf-state-file",
                                       daemon=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Follow the registry and the workers' last boxes, fetch the others' registry, but do
        not join yet: the instance announces itself (:meth:`join`) once its workers are
        ready."""

        self._subs.append(self.session.declare_subscriber(self.keys.registry_all(),
                                                          self._on_registry))
        self._subs.append(self.session.declare_subscriber(self.keys.all_last_boxes(),
                                                          self._on_last_boxes))
        self._queryable = self.session.declare_queryable(self.keys.registry_all(),
                                                         self._on_registry_query)
        if self.state is not None:
            # in a fleet the live instances' registry is the truth: a session stopped while
            # this one was down must not come back from its file
            others = self._live_instances()
            resumed = [] if others else self.state.load()
            for spec in resumed:
                self._merge_spec(spec)
            log.info("%d session(s) from %s%s", len(resumed), self.state.path,
                     f" (not read: instances {', '.join(others)} hold the registry)"
                     if others else "")
            self._saver.start()
        self._fetch_registry()
        self._subs.append(self.session.liveliness().declare_subscriber(
            self.keys.all_instances(), self._on_member, history=True))
        self._thread.start()

    def join(self) -> None:
        self._token = self.session.liveliness().declare_token(
            self.keys.instance_token(self.instance_id))
        with self.lock:
            self.members.add(self.instance_id)
            self.joined = True
        self._changed.set()

    def close(self) -> None:
        self._closing = True
        self._changed.set()
        if self.state is not None:
            self._save()  # what runs now resumes when this instance starts again
        if self._token is not None:
            self._token.undeclare()
        for sub in self._subs:
            sub.undeclare()
        if self._queryable is not None:
            self._queryable.undeclare()

    # ------------------------------------------------------------------ queries
    def live(self) -> list[str]:
        with self.lock:
            return sorted(self.members)

    def owner_of(self, key: str) -> str:
        """The live instance that owns ``key`` (a stream id, or any key the instances must agree
        on, e.g. which one answers a request about nothing in particular)."""
        with self.lock:
            members = self.members or {self.instance_id}
            return owner(key, members)

    def request_rebalance(self) -> None:
        self._changed.set()

    def mine(self, key: str) -> bool:
        return self.owner_of(key) == self.instance_id

    def spec(self, session_id: str) -> SessionSpec | None:
        with self.lock:
            return self.specs.get(session_id)

    def all_specs(self) -> list[SessionSpec]:
        with self.lock:
            return list(self.specs.values())

    def resume_point(self, session_id: str
                     ) -> tuple[tuple[float, float, float, float], int | None, bool]:
        """Where a session taken over starts again: (box, frame_seq, resumed). From its last
        published box on the next frame; from its start box if it never published one."""
        with self.lock:
            last = self.last.get(session_id)
            spec = self.specs.get(session_id)
        if last is not None:
            return last[1], last[0] + 1, True
        assert spec is not None
        return spec.box, spec.frame_seq, False

    def _live_instances(self) -> list[str]:
        """The other instances live now (their liveliness tokens)."""
        replies = self.session.liveliness().get(self.keys.all_instances(), timeout=2.0)
        return sorted({str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies
                       if r.ok is not None} - {self.instance_id})

    def _fetch_registry(self) -> None:
        """Ask every other instance for its registry and merge it (with its last boxes)."""
        import zenoh

        for reply in self.session.get(self.keys.registry_all(), timeout=2.0,
                                      target=zenoh.QueryTarget.ALL):
            if reply.ok is not None:
                self._merge(reply.ok.payload.to_bytes())

    # ------------------------------------------------------------------ registry writes
    def publish(self, spec: SessionSpec) -> None:
        with self.lock:
            self._registered(spec)
        self.session.put(self.keys.registry(spec.session_id), encode(spec))

    def withdraw(self, session_id: str) -> None:
        with self.lock:
            self.specs.pop(session_id, None)
            self.last.pop(session_id, None)
            self._version += 1
        self.session.delete(self.keys.registry(session_id))

    # ------------------------------------------------------------------ Zenoh callbacks
    def _on_member(self, sample: Any) -> None:
        import zenoh

        instance = str(sample.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.members.add(instance)
                if instance != self.instance_id:
                    self._resync.set()
            elif instance != self.instance_id:
                self.members.discard(instance)
        log.info("instance %s %s; live: %s", instance,
                 "joined" if sample.kind == zenoh.SampleKind.PUT else "left", self.live())
        self._changed.set()

    def _on_registry(self, sample: Any) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.DELETE:
            sid = str(sample.key_expr).rsplit("/", 1)[-1]
            with self.lock:
                self.specs.pop(sid, None)
                self.last.pop(sid, None)
                self._version += 1
        else:
            self._merge(sample.payload.to_bytes())
        self._changed.set()

    def _merge(self, payload: bytes) -> None:
        try:
            spec = decode(payload, expected=SessionSpec)
        except SchemaError as exc:
            log.warning("ignoring a malformed registry entry: %s", exc)
            return
        self._merge_spec(spec)

    def _merge_spec(self, spec: SessionSpec) -> None:
        with self.lock:
            self._registered(spec)
            if spec.last_seq is not None and spec.last_box is not None:
                self._keep(spec.session_id, (spec.last_seq, spec.last_box))

    def _on_registry_query(self, query: Any) -> None:
        """A joining instance asks what runs: every known session, with its last box."""
        for spec in self._entries():
            query.reply(self.keys.registry(spec.session_id), encode(spec))

    def _entries(self) -> list[SessionSpec]:
        """Every known session, with its last usable box."""
        with self.lock:
            entries = [(s, self.last.get(s.session_id)) for s in self.specs.values()]
        return [spec.model_copy(update={"last_seq": last[0], "last_box": last[1]})
                if last is not None and usable_box(last[1]) else spec
                for spec, last in entries]

    def _save(self) -> None:
        assert self.state is not None
        with self._save_lock:
            with self.lock:
                version = self._version
            try:
                self.state.save(self._entries())
                self._saved = version
            except OSError as exc:  # a full disk must not stop the service; said, retried
                log.error("state file %s not written: %s", self.state.path, exc)

    def _save_loop(self) -> None:
        while not self._closing:
            time.sleep(SAVE_PERIOD_S)
            if self._version != self._saved and not self._closing:
                self._save()

    def _on_last_boxes(self, sample: Any) -> None:
        try:
            message = decode(sample.payload.to_bytes(), expected=LastBoxes)
        except SchemaError as exc:
            log.debug("ignoring malformed last boxes: %s", exc)  # a flood must not fill logs
            return
        self.note_boxes(message)

    def note_boxes(self, message: LastBoxes) -> None:
        """Keep each session's newest usable box of ``message`` (of a session not registered
        yet, until its spec comes)."""
        with self.lock:
            for entry in message.boxes:
                if not usable_box(entry.box):
                    continue
                if entry.session_id in self.specs:
                    self._keep(entry.session_id, (entry.frame_seq, entry.box))
                else:
                    self.early[entry.session_id] = (entry.frame_seq, entry.box)
                    self.early.move_to_end(entry.session_id)
                    while len(self.early) > EARLY_BOXES:
                        self.early.popitem(last=False)

    def _keep(self, session_id: str,
              last: tuple[int, tuple[float, float, float, float]]) -> None:
        """``last`` as the session's last box if it is newer (call with ``lock`` held)."""
        known = self.last.get(session_id)
        if known is None or known[0] < last[0]:
            self.last[session_id] = last
            self._version += 1

    def _registered(self, spec: SessionSpec) -> None:
        """``spec`` is known now: a box that came before it counts (call with ``lock``)."""
        self.specs[spec.session_id] = spec
        self._version += 1
        early = self.early.pop(spec.session_id, None)
        if early is not None:
            self._keep(spec.session_id, early)

    def _notify_loop(self) -> None:
        while True:
            self._changed.wait()
            if self.linked is not None:
                while not self._closing and not self.linked():
                    time.sleep(LINK_POLL_S)
            self._changed.clear()
            if self._closing:
                return
            if self._resync.is_set():
                self._resync.clear()
                try:
                    self._fetch_registry()
                except Exception:  # the rebalance goes on with what is known
                    log.exception("could not merge the other instances' registries")
            if self.joined and self.on_change is not None:
                try:
                    self.on_change()
                except Exception:  # the next change tries again
                    log.exception("rebalancing failed")
