"""Zenoh key expressions of the wire contract, built and parsed in one place.

Every key is ``<prefix>/...`` (``arcf/v1`` by default, a setting). Ids placed in keys are checked
against :data:`~arcf.schemas.messages.ID_PATTERN`, which excludes ``/`` and every Zenoh special
character (``*``, ``$``, ``?``, ``#``, ``@``): an id is always exactly one literal chunk, so a
client cannot reach another stream's keys (or all of them) through a crafted id, and a parser
can split keys on ``/`` without ambiguity. The prefix follows the same rule per chunk.

This module is pure string work; it does not import zenoh. Parsers accept a ``str`` or anything
whose ``str()`` is the key, such as a ``zenoh.KeyExpr``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from .messages import ID_PATTERN

__all__ = [
    "DEFAULT_PREFIX",
    "KEY_ROUTES",
    "InvalidKey",
    "KeyRoute",
    "KeySpace",
    "check_id",
    "is_valid_id",
]

#: Default key prefix; the version in it lets a v2 service run beside v1 without crosstalk.
DEFAULT_PREFIX = "arcf/v1"

_ID_RE = re.compile(ID_PATTERN)


class InvalidKey(ValueError):
    """An id, prefix or key expression that does not fit the contract's key layout."""


def is_valid_id(value: object) -> bool:
    """True if ``value`` is a str usable as a stream/session/instance/worker id."""
    return isinstance(value, str) and _ID_RE.match(value) is not None


def check_id(value: object, what: str = "id") -> str:
    """Return ``value`` if it is a valid id, else raise :class:`InvalidKey` naming ``what``."""
    if not is_valid_id(value):
        raise InvalidKey(
            f"{what} must match {ID_PATTERN} (1-64 of A-Z a-z 0-9 _ . -), got {value!r}"
        )
    return value  # type: ignore[return-value]


@dataclass(frozen=True)
class KeyRoute:
    """One row of the key-expression table of the design (exported to ``index.json``)."""

    name: str
    key: str
    who: str
    what: str
    messages: tuple[str, ...]


#: The key-expression table of ``docs/wire-contract.md``.
KEY_ROUTES: tuple[KeyRoute, ...] = (
    KeyRoute(
        "frames",
        "<prefix>/streams/<stream>/frames",
        "ground station puts",
        "frame messages (compressed or raw images)",
        ("frame",),
    ),
    KeyRoute(
        "results",
        "<prefix>/streams/<stream>/sessions/<session>/results",
        "service puts",
        "result messages, one per processed frame per session",
        ("result",),
    ),
    KeyRoute(
        "results as JSON",
        "<prefix>/json/streams/<stream>/sessions/<session>/results",
        "service puts, only while someone subscribes",
        "the same results as JSON (the form of the exported schemas, NaN as null), for tools "
        "that print text, such as Zenoh's z_sub",
        ("result",),
    ),
    KeyRoute(
        "errors",
        "<prefix>/streams/<stream>/errors",
        "service puts",
        "error messages about that stream's frames: refused ones (undecodable, oversized, "
        "rate-limited, out-of-sequence, wrong key, no session) and notices (a restarted "
        "numbering); the codes are in the contract's error table",
        ("error",),
    ),
    KeyRoute(
        "control",
        "<prefix>/control",
        "service queryable; clients get with a request as payload",
        "start, reinit, stop, status_request and presets_request requests; the reply is an "
        "ack (status for status_request, presets for presets_request) or an error",
        ("start", "reinit", "stop", "status_request", "presets_request", "ack", "status",
         "presets", "error"),
    ),
    KeyRoute(
        "workers",
        "<prefix>/workers/<instance>/<worker>",
        "service liveliness tokens",
        "one per live worker process (no payload)",
        (),
    ),
    KeyRoute(
        "instances",
        "<prefix>/instances/<instance>",
        "service liveliness tokens",
        "one per live service instance (no payload); the live set decides stream ownership",
        (),
    ),
    KeyRoute(
        "registry",
        "<prefix>/registry/<session>",
        "service puts/deletes; every instance also answers queries on <prefix>/registry/*",
        "the spec of every running session, so that a surviving instance can resume it",
        ("session_spec",),
    ),
    KeyRoute(
        "boxes",
        "<prefix>/boxes/<instance>/<worker>",
        "service puts",
        "the last box of every session a worker runs, at a bounded rate, so that a surviving "
        "instance resumes them from there (instances follow these, not every result)",
        ("last_boxes",),
    ),
    KeyRoute(
        "clients",
        "<prefix>/clients/<client>",
        "ground station liveliness tokens (optional)",
        "a station that declares one and names it in start (client_id) has its sessions end "
        "when the token is gone longer than the service's client_grace_s",
        (),
    ),
)


@dataclass(frozen=True)
class KeySpace:
    """Builds and parses the contract's keys under one ``prefix``.

    >>> keys = KeySpace()
    >>> keys.results("cam1", "s1")
    'arcf/v1/streams/cam1/sessions/s1/results'
    >>> keys.stream_of_frames_key("arcf/v1/streams/cam1/frames")
    'cam1'
    """

    prefix: str = DEFAULT_PREFIX

    def __post_init__(self) -> None:
        prefix = self.prefix
        if not isinstance(prefix, str) or not prefix:
            raise InvalidKey(f"key prefix must be a non-empty string, got {prefix!r}")
        if prefix.startswith("/") or prefix.endswith("/"):
            raise InvalidKey(f"key prefix must not start or end with '/', got {prefix!r}")
        for chunk in prefix.split("/"):
            if not is_valid_id(chunk):
                raise InvalidKey(
                    f"key prefix chunks must match {ID_PATTERN} (no wildcards, '$', '?', '#', "
                    f"'@' or empty chunks), got {prefix!r}"
                )

    # -- builders ------------------------------------------------------------------------------

    def frames(self, stream: str) -> str:
        """``<prefix>/streams/<stream>/frames``: where a ground station puts a stream's frames."""
        return f"{self.prefix}/streams/{check_id(stream, 'stream id')}/frames"

    def all_frames(self) -> str:
        """``<prefix>/streams/*/frames``: the service's subscription to every stream."""
        return f"{self.prefix}/streams/*/frames"

    def results(self, stream: str, session: str) -> str:
        """``<prefix>/streams/<stream>/sessions/<session>/results``: one session's results."""
        stream = check_id(stream, "stream id")
        return f"{self.prefix}/streams/{stream}/sessions/{check_id(session, 'session id')}/results"

    def json_results(self, stream: str, session: str) -> str:
        """``<prefix>/json/streams/<stream>/sessions/<session>/results``: the same results as
        JSON, published only while a subscriber matches it."""
        return f"{self.prefix}/json/{self.results(stream, session)[len(self.prefix) + 1:]}"

    def results_of_stream(self, stream: str) -> str:
        """``<prefix>/streams/<stream>/sessions/*/results``: every session's results."""
        return f"{self.prefix}/streams/{check_id(stream, 'stream id')}/sessions/*/results"

    def all_results(self) -> str:
        """``<prefix>/streams/*/sessions/*/results``: every result (monitoring, recording)."""
        return f"{self.prefix}/streams/*/sessions/*/results"

    def errors(self, stream: str) -> str:
        """``<prefix>/streams/<stream>/errors``: errors about a stream's frames."""
        return f"{self.prefix}/streams/{check_id(stream, 'stream id')}/errors"

    def all_errors(self) -> str:
        """``<prefix>/streams/*/errors``: errors about every stream's frames."""
        return f"{self.prefix}/streams/*/errors"

    def control(self) -> str:
        """``<prefix>/control``: the service's queryable for requests."""
        return f"{self.prefix}/control"

    def worker_token(self, instance: str, worker: str) -> str:
        """``<prefix>/workers/<instance>/<worker>``: a worker process's liveliness token."""
        instance = check_id(instance, "instance id")
        return f"{self.prefix}/workers/{instance}/{check_id(worker, 'worker id')}"

    def workers_of_instance(self, instance: str) -> str:
        """``<prefix>/workers/<instance>/*``: the tokens of one service instance's workers."""
        return f"{self.prefix}/workers/{check_id(instance, 'instance id')}/*"

    def all_workers(self) -> str:
        """``<prefix>/workers/*/*``: every worker token of every instance."""
        return f"{self.prefix}/workers/*/*"

    def client_token(self, client: str) -> str:
        """``<prefix>/clients/<client>``: a ground station's liveliness token (optional: the
        sessions it starts with this ``client_id`` end when it is gone)."""
        return f"{self.prefix}/clients/{check_id(client, 'client id')}"

    def all_client_tokens(self) -> str:
        return f"{self.prefix}/clients/*"

    def publisher_token(self, stream: str, client: str) -> str:
        """``<prefix>/publishers/<stream>/<client>``: a station's liveliness token while it
        publishes a stream's frames (so that a viewer finds streams no session tracks yet)."""
        stream = check_id(stream, "stream id")
        return f"{self.prefix}/publishers/{stream}/{check_id(client, 'client id')}"

    def all_publisher_tokens(self) -> str:
        """``<prefix>/publishers/*/*``: every stream's publishers."""
        return f"{self.prefix}/publishers/*/*"

    def instance_token(self, instance: str) -> str:
        """``<prefix>/instances/<instance>``: a service instance's liveliness token."""
        return f"{self.prefix}/instances/{check_id(instance, 'instance id')}"

    def all_instances(self) -> str:
        """``<prefix>/instances/*``: the tokens of every live service instance."""
        return f"{self.prefix}/instances/*"

    def registry(self, session: str) -> str:
        """``<prefix>/registry/<session>``: a running session's spec."""
        return f"{self.prefix}/registry/{check_id(session, 'session id')}"

    def registry_all(self) -> str:
        """``<prefix>/registry/*``: every running session's spec."""
        return f"{self.prefix}/registry/*"

    def last_boxes(self, instance: str, worker: str) -> str:
        """``<prefix>/boxes/<instance>/<worker>``: its sessions' last boxes."""
        return (f"{self.prefix}/boxes/{check_id(instance, 'instance id')}/"
                f"{check_id(worker, 'worker id')}")

    def all_last_boxes(self) -> str:
        """``<prefix>/boxes/*/*``: every worker's sessions' last boxes."""
        return f"{self.prefix}/boxes/*/*"

    # -- parsers -------------------------------------------------------------------------------

    def _chunks(self, key: object, shape: tuple[str | None, ...], what: str) -> list[str]:
        """The id chunks of ``key`` laid out as ``<prefix>/`` + ``shape``.

        ``shape`` lists the chunks after the prefix: a literal, or ``None`` for an id.
        """
        text = str(key)
        head = self.prefix + "/"
        if not text.startswith(head):
            raise InvalidKey(f"{text!r} is not under the key prefix {self.prefix!r}")
        chunks = text[len(head) :].split("/")
        if len(chunks) != len(shape):
            raise InvalidKey(f"{text!r} is not a {what} key")
        ids = []
        for chunk, expect in zip(chunks, shape, strict=True):
            if expect is None:
                if not is_valid_id(chunk):
                    raise InvalidKey(f"{text!r} is not a {what} key: bad id {chunk!r}")
                ids.append(chunk)
            elif chunk != expect:
                raise InvalidKey(f"{text!r} is not a {what} key")
        return ids

    def stream_of_frames_key(self, key: object) -> str:
        """The stream id of a ``frames`` key (e.g. of a received sample's ``key_expr``)."""
        return self._chunks(key, ("streams", None, "frames"), "frames")[0]

    def stream_of_errors_key(self, key: object) -> str:
        """The stream id of an ``errors`` key."""
        return self._chunks(key, ("streams", None, "errors"), "errors")[0]

    def parse_results_key(self, key: object) -> tuple[str, str]:
        """``(stream, session)`` of a ``results`` key."""
        stream, session = self._chunks(
            key, ("streams", None, "sessions", None, "results"), "results"
        )
        return stream, session

    def parse_publisher_key(self, key: object) -> tuple[str, str]:
        """``(stream, client)`` of a publisher liveliness token key."""
        stream, client = self._chunks(key, ("publishers", None, None), "publisher token")
        return stream, client

    def parse_worker_key(self, key: object) -> tuple[str, str]:
        """``(instance, worker)`` of a worker liveliness token key."""
        instance, worker = self._chunks(key, ("workers", None, None), "worker token")
        return instance, worker

    def is_control_key(self, key: object) -> bool:
        """True if ``key`` is exactly the control key."""
        return str(key) == self.control()
