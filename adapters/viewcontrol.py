"""The live view's tracking control: start a session on a drawn box, re-initialise or stop one.

It controls what the service tracks, so it is off unless the operator turns it on
(``arcf-view --allow-control``), a request must carry the view's credential, and it must show
that it comes from the view's own page:

- **Credential**: ``Authorization: Bearer <token>``, the view's control token (random at each
  start unless the operator gives one with ``--control-token-file``). The view prints its
  address with the token in the fragment (``http://host:8090/#token=...``): the page keeps it
  for the tab and sends it with every control request; a fragment is never sent to a server,
  so it stays out of logs and ``Referer`` headers. Whoever reaches the page without it watches
  but cannot control.

- **Host**: the request's ``Host`` is an IP address, ``localhost``, or a name the operator
  allowed (``--allow-host``). A web page elsewhere that rebinds its own name to this machine's
  address (DNS rebinding) sends its own name and is refused.
- **Origin**: a browser names the page that sends a request; when it does, that page must be
  this server (same scheme, host and port): another site open in the same browser is refused.
- **Content type** ``application/json``: a browser sends that to another origin only after a
  CORS preflight, which this server does not grant.

Each refusal and each bad request is counted (``LiveView.counts``) and answered with a clear
JSON reason; the service's own refusals (an unknown preset, a box it cannot use, a session it
does not know) come back with the service's ``code`` and ``message``.

Sessions started here belong to the view's client: they end (after the service's
``client_grace_s``) when ``arcf-view`` stops, like any station's.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import logging
import math
import secrets
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from http import HTTPStatus
from typing import Any
from urllib.parse import urlsplit

from arcf.client import ServiceError, TrackingClient

log = logging.getLogger(__name__)

#: the preset a drawn box starts when the page names none (the library's default)
DEFAULT_PRESET = "arcf-hc"
#: the largest side a box may have, pixels (a 16K frame's)
MAX_SIDE = 16384.0
#: the shortest control token an operator may give (a generated one has 32 characters)
MIN_TOKEN = 16


@dataclass(frozen=True)
class Reply:
    """What the page gets back: an HTTP status and a JSON body."""

    status: HTTPStatus
    body: dict[str, Any] = field(default_factory=dict)


class Refused(Exception):
    """A control request that is not carried out; its reply says why."""

    def __init__(self, status: HTTPStatus, reason: str, code: str) -> None:
        super().__init__(reason)
        self.reply = Reply(status, {"code": code, "message": reason})


def _host_name(host: str) -> str:
    """The name in a ``Host`` header (``name:port``, ``[v6]:port``), lower case."""
    if host.startswith("["):
        return host[1:].partition("]")[0].lower()
    return host.rpartition(":")[0].lower() if host.count(":") == 1 else host.lower()


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class ViewControl:
    """Checks and carries out the page's control requests through the view's client."""

    def __init__(self, client: TrackingClient, *, enabled: bool,
                 allowed_hosts: Sequence[str] = (), count: Callable[[str], None] | None = None,
                 token: str | None = None) -> None:
        self.client, self.enabled = client, enabled
        if token is not None and len(token) < MIN_TOKEN:
            raise ValueError(f"a control token has at least {MIN_TOKEN} characters")
        #: the credential a control request must carry (``Authorization: Bearer``)
        self.token = token if token is not None else secrets.token_urlsafe(24)
        self.allowed_hosts = {"localhost", *(h.lower() for h in allowed_hosts)}
        self._count = count or (lambda reason: None)
        self._presets: list[str] | None = None

    # ------------------------------------------------------------------ what the page asks
    def config(self) -> dict[str, Any]:
        """Whether control is on, and the presets a drawn box may start."""
        if self.enabled and self._presets is None:
            try:
                self._presets = [p.name for p in self.client.presets(timeout=2.0).presets]
            except (ServiceError, TimeoutError) as exc:
                log.warning("presets not known yet: %s", exc)
        presets = self._presets or [DEFAULT_PRESET]
        return {"control": self.enabled, "presets": presets,
                "preset": DEFAULT_PRESET if DEFAULT_PRESET in presets else presets[0]}

    def handle(self, action: str, target: str, headers: Mapping[str, str],
               body: bytes) -> Reply:
        """``action`` (``start`` on stream ``target``; ``reinit`` or ``stop`` of session
        ``target``) if the request may control tracking and is well formed."""
        try:
            self._check(headers)
            request = self._parse(body, action)
            return self._carry_out(action, target, request)
        except Refused as exc:
            self._count("control_" + str(exc.reply.body["code"]))
            log.info("control %s %s refused: %s", action, target, exc)
            return exc.reply

    # ------------------------------------------------------------------ checks
    def _check(self, headers: Mapping[str, str]) -> None:
        if not self.enabled:
            raise Refused(HTTPStatus.FORBIDDEN, "tracking control is off: the operator starts "
                          "arcf-view with --allow-control to turn it on", "control_off")
        host = headers.get("Host") or ""
        name = _host_name(host)
        if not (_is_ip(name) or name in self.allowed_hosts):
            raise Refused(HTTPStatus.FORBIDDEN, f"host {name!r} is not this view's (an IP "
                          "address, localhost, or a name given with --allow-host)", "bad_host")
        origin = headers.get("Origin")
        if origin is not None:
            parts = urlsplit(origin)
            if parts.scheme != "http" or parts.netloc.lower() != host.lower():
                raise Refused(HTTPStatus.FORBIDDEN, f"a page from {origin!r} may not control "
                              "this view", "bad_origin")
        scheme, _, given = (headers.get("Authorization") or "").partition(" ")
        if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(),
                                                                  self.token.encode()):
            raise Refused(HTTPStatus.UNAUTHORIZED, "tracking control needs the view's token: "
                          "open the address arcf-view printed (it ends in #token=...)",
                          "bad_credential")
        kind = (headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if kind != "application/json":
            raise Refused(HTTPStatus.UNSUPPORTED_MEDIA_TYPE,
                          "a control request's body is application/json", "bad_request")

    def _parse(self, body: bytes, action: str) -> dict[str, Any]:
        try:
            request = json.loads(body or b"{}")
        except (ValueError, UnicodeDecodeError) as exc:
            raise Refused(HTTPStatus.BAD_REQUEST, f"the body is not JSON: {exc}",
                          "bad_request") from exc
        if not isinstance(request, dict):
            raise Refused(HTTPStatus.BAD_REQUEST, "the body is a JSON object", "bad_request")
        allowed = {"start": {"box", "preset", "frame_seq"}, "reinit": {"box", "frame_seq"},
                   "stop": set()}[action]
        extra = set(request) - allowed
        if extra:
            raise Refused(HTTPStatus.BAD_REQUEST, f"unknown field(s) {sorted(extra)} for "
                          f"{action} (it takes {sorted(allowed) or 'none'})", "bad_request")
        if "box" in allowed:
            request["box"] = _box(request.get("box"))
        seq = request.get("frame_seq")
        if seq is not None and (type(seq) is not int or not 0 <= seq < 2**63):
            raise Refused(HTTPStatus.BAD_REQUEST, "frame_seq is a frame number (an integer "
                          ">= 0) or absent", "bad_request")
        preset = request.get("preset", DEFAULT_PRESET)
        if action == "start" and (not isinstance(preset, str) or not 0 < len(preset) <= 64):
            raise Refused(HTTPStatus.BAD_REQUEST, "preset is a preset's name", "bad_request")
        return request

    # ------------------------------------------------------------------ the service
    def _carry_out(self, action: str, target: str, request: dict[str, Any]) -> Reply:
        try:
            if action == "start":
                ack = self.client.start(target, request["box"],
                                        preset=request.get("preset", DEFAULT_PRESET),
                                        frame_seq=request.get("frame_seq"))
                log.info("session %s started on %s at %s", ack.session_id, target,
                         request["box"])
                return Reply(HTTPStatus.CREATED, {"session_id": ack.session_id})
            if action == "reinit":
                ack = self.client.reinit(target, request["box"],
                                         frame_seq=request.get("frame_seq"))
                log.info("session %s re-initialised at %s", target, request["box"])
            else:
                ack = self.client.stop(target)
                log.info("session %s stopped", target)
            return Reply(HTTPStatus.OK, {"session_id": ack.session_id})
        except ServiceError as exc:
            status = (HTTPStatus.NOT_FOUND if exc.code == "unknown_session"
                      else HTTPStatus.UNPROCESSABLE_ENTITY)
            raise Refused(status, exc.error.message, exc.code) from exc
        except TimeoutError as exc:
            raise Refused(HTTPStatus.GATEWAY_TIMEOUT, f"the service did not answer: {exc}",
                          "no_answer") from exc


def _box(value: Any) -> list[float]:
    """``[x, y, w, h]``: four finite numbers, a positive size no larger than ``MAX_SIDE``."""
    if (not isinstance(value, list) or len(value) != 4
            or not all(type(v) in (int, float) for v in value)):
        raise Refused(HTTPStatus.BAD_REQUEST, "box is [x, y, width, height] in the frame's "
                      "pixels (1-based, as results)", "bad_request")
    box = [float(v) for v in value]
    if not all(math.isfinite(v) for v in box) or not all(0 < v <= MAX_SIDE for v in box[2:]):
        raise Refused(HTTPStatus.BAD_REQUEST, f"box {value} has no usable size", "bad_request")
    return box
