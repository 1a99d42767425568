"""Pydantic models of every message of the wire contract (``docs/wire-contract.md``).

These models are the source of truth: the msgpack codec (:mod:`arcf.schemas.codec`) validates every
incoming map against them and the JSON Schema files in ``schemas/json`` are generated from them.

Design choices that apply to every model:

* ``extra="forbid"`` for what stations send (and instances exchange): a misspelt field is an
  error, not something silently ignored (a client that sends ``frameseq`` would otherwise start a
  session on the wrong frame without noticing).
* What the service sends to stations (:class:`Reply` and the models inside it) is open for
  additions within a version: a newer service may add optional fields, and a decoder ignores the
  fields it does not know, so an older station keeps working (``extra="ignore"``).
* ``frozen=True``: a decoded message is a value; nothing downstream may change what was received.
* Scalars are *strict*: ``"5"``, ``5.0`` or ``True`` are not a valid ``seq``, a string is not a
  number and bytes are not text. msgpack carries types, so a peer that sends the wrong one has a
  bug worth reporting rather than a value worth guessing. Floats accept msgpack ints (a box
  ``[10, 20, 30, 40]`` is fine).
* Integers are bounded to the signed 64-bit range so that every valid message can be encoded by
  msgpack and read by clients in languages without big integers.
* The wire ``type`` of a model is a class variable (``Frame.type == "frame"``), not a field: the
  codec writes it in the envelope next to ``v`` and uses it to pick the model when decoding.
* Optional fields default to ``None``; the codec omits ``None`` fields on the wire and accepts
  both an absent key and an explicit msgpack ``nil``.
"""

from __future__ import annotations

import math
from enum import Enum
from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictBool,
    StrictStr,
    ValidationError,
    ValidatorFunctionWrapHandler,
    WrapValidator,
    model_validator,
)
from pydantic_core import PydanticCustomError

__all__ = [
    "BOX_ERROR_TYPE",
    "ID_PATTERN",
    "INT64_MAX",
    "MAX_BOX_COORD",
    "MAX_OVERRIDES",
    "MESSAGE_TYPES",
    "OVERRIDE_KEY_PATTERN",
    "SCHEMA_VERSION",
    "Ack",
    "Box",
    "Encoding",
    "ErrorCode",
    "ErrorMessage",
    "Frame",
    "LastBox",
    "LastBoxes",
    "Message",
    "OpenModel",
    "ParameterInfo",
    "PresetInfo",
    "Presets",
    "PresetsRequest",
    "ReinitRequest",
    "Reply",
    "Result",
    "ResultBox",
    "ResultStatus",
    "SessionInfo",
    "SessionSpec",
    "StartRequest",
    "Status",
    "StatusRequest",
    "StopRequest",
    "TrackState",
    "WireModel",
]

#: Version written in the ``v`` envelope key of every message. Bump it only for incompatible
#: changes; the decoder rejects any other version with ``unsupported_version``.
SCHEMA_VERSION = 1

#: Stream, session, request, instance and worker ids, and preset names. The character set
#: excludes ``/``, ``*``, ``$``, ``?``, ``#`` and ``@`` so that an id is always one literal Zenoh
#: key-expression chunk: a client cannot subscribe to other streams by naming its stream ``*``.
ID_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"

#: Parameter names in ``overrides``: identifiers, dotted for nested parameters
#: (``scale_filter.n_scales``).
OVERRIDE_KEY_PATTERN = r"^[A-Za-z_][A-Za-z0-9_.]{0,63}$"

#: ``overrides`` holds at most this many entries (a request is small; a huge map is abuse).
MAX_OVERRIDES = 32

#: Longest string value accepted in ``overrides``.
MAX_OVERRIDE_STR = 256

#: Largest integer of the contract: msgpack and most client languages use 64-bit integers.
INT64_MAX = 2**63 - 1

#: Largest magnitude of a request box's coordinates and size, in pixels. Far beyond any camera
#: (8K is 7680 px wide) yet small enough that a tracker sized from the box cannot be made to
#: allocate absurd amounts of memory.
MAX_BOX_COORD = 100_000.0

#: pydantic error ``type`` raised for a bad box; the codec maps it to ``ErrorCode.INVALID_BOX``.
BOX_ERROR_TYPE = "invalid_box"


class ErrorCode(str, Enum):
    """Codes of ``error`` messages, so that clients can react without parsing English text."""

    MALFORMED_MESSAGE = "malformed_message"
    UNSUPPORTED_VERSION = "unsupported_version"
    UNKNOWN_TYPE = "unknown_type"
    INVALID_REQUEST = "invalid_request"
    UNKNOWN_STREAM = "unknown_stream"
    UNKNOWN_SESSION = "unknown_session"
    INVALID_BOX = "invalid_box"
    UNKNOWN_PRESET = "unknown_preset"
    INVALID_PARAMETER = "invalid_parameter"
    DECODE_ERROR = "decode_error"
    OVERSIZED_PAYLOAD = "oversized_payload"
    NO_SESSION = "no_session"
    #: A frame whose ``seq`` is not above the stream's last one (duplicate or out of order).
    STALE_FRAME = "stale_frame"
    #: A frame whose ``seq`` is more than ``max_seq_gap`` ahead of the stream's last one.
    SEQUENCE_JUMP = "sequence_jump"
    #: Not a refusal: the stream's numbering restarted (``resync_frames`` frames in a row
    #: agreed on it); the frames follow the new numbering from here.
    SEQUENCE_RESTARTED = "sequence_restarted"
    #: A frame put on a key expression with wildcards, or on another stream's key.
    INVALID_KEY = "invalid_key"
    #: A frame a session's tracker cannot use (its size changed mid-stream: reinit).
    INVALID_FRAME = "invalid_frame"
    #: A session the service ended by itself: no frame for ``session_idle_s``, or its
    #: station's liveliness token gone for longer than ``client_grace_s``.
    SESSION_EXPIRED = "session_expired"
    #: Not a refusal: the code of a ``stale`` result. No frame of the session's stream has
    #: reached the service for ``stale_after_s``, so its last box is not current.
    NO_FRAMES = "no_frames"
    #: A stream sending more frames per second than ``max_stream_fps``.
    RATE_LIMITED = "rate_limited"
    #: An image whose header declares more pixels than ``max_pixels`` (decompression bomb).
    IMAGE_TOO_LARGE = "image_too_large"
    #: A service-wide cap (e.g. ``max_sessions``) would be exceeded.
    LIMIT_EXCEEDED = "limit_exceeded"
    #: A ``stop`` or ``reinit`` without the session's control token (the one its ``start``
    #: was acknowledged with), where the service's ``session_control`` is ``owner``.
    FORBIDDEN = "forbidden"
    #: A stream whose frames were being processed when worker processes died
    #: ``quarantine_after`` times: its sessions end, and starts on it are refused for
    #: ``quarantine_s``.
    QUARANTINED = "quarantined"
    #: Not a refusal: the code of the ``stopped`` result of a session interrupted, not
    #: ended: its instance is shutting down or lost its place in the cluster, and the session
    #: stays registered. It resumes (status ``resumed``) on a live instance, or on this one
    #: when it starts again with its state file.
    INTERRUPTED = "interrupted"
    INTERNAL = "internal"


class Encoding(str, Enum):
    """How a frame's ``payload`` is encoded.

    ``jpeg``/``png`` are compressed files (what a ground station normally sends over a radio
    link); ``bgr8``/``gray8`` are raw row-major 8-bit pixels (OpenCV's layout, no padding), for
    same-host producers that would only waste CPU compressing; ``h264``/``h265`` are one
    access unit of a video stream (Annex B byte stream, start codes included), as a drone's
    encoder sends them: each depends on the ones before it, so a stream's units are decoded in
    order, every one, from a keyframe on (docs/wire-contract.md, "Video streams").
    """

    JPEG = "jpeg"
    PNG = "png"
    BGR8 = "bgr8"
    GRAY8 = "gray8"
    H264 = "h264"
    H265 = "h265"

    @property
    def is_raw(self) -> bool:
        """True for raw pixel encodings, whose size must be declared in the frame."""
        return self in (Encoding.BGR8, Encoding.GRAY8)

    @property
    def channels(self) -> int | None:
        """Bytes per pixel of a raw encoding, ``None`` for compressed ones."""
        return {Encoding.BGR8: 3, Encoding.GRAY8: 1}.get(self)

    @property
    def is_video(self) -> bool:
        """True for access units of a video stream (decoded in order, by one decoder)."""
        return self in (Encoding.H264, Encoding.H265)


class TrackState(str, Enum):
    """What the tracker makes of its own response (the library's ``arcf.state.TrackState``,
    spelt out here so that a station needs only the schemas)."""

    #: The confidence is high enough: the box is the target's.
    TRACKING = "tracking"
    #: The confidence fell: the target is probably hidden or blurred; the box is the filter's
    #: best guess and the appearance model may not be learning.
    COASTING = "coasting"
    #: The tracker no longer believes it sees the target (re-acquisition, when on, searches).
    LOST = "lost"


class ResultStatus(str, Enum):
    """What happened to a session on the frame a ``result`` is about."""

    INITIALIZED = "initialized"
    TRACKING = "tracking"
    REINITIALIZED = "reinitialized"
    #: Taken over by another worker or instance after a failure or a rebalance, and started
    #: again from the last published box.
    RESUMED = "resumed"
    #: The last result of a session this instance no longer runs: the service is shutting
    #: down, or the instance lost its place in the cluster (another instance resumes it if one
    #: is live). ``frame_seq`` is the session's last frame.
    STOPPED = "stopped"
    ERROR = "error"
    #: Not about a frame: no frame of the session's stream has reached the service for
    #: ``stale_after_s`` (code ``no_frames``), so the session's last box is not current and
    #: must not be followed. Box and signals are NaN, ``track_state`` is absent (it is not a
    #: lost target: the tracker saw nothing), ``frame_seq`` is the session's last frame (0
    #: before its first). Repeated every ``stale_after_s`` while it lasts; the session goes
    #: on, and its next frame's result is an ordinary one.
    STALE = "stale"


# ---------------------------------------------------------------------------------------------
# Field types
# ---------------------------------------------------------------------------------------------

Id = Annotated[StrictStr, Field(pattern=ID_PATTERN)]
#: A session's control token: a random URL-safe string (``secrets.token_urlsafe``)
ControlToken = Annotated[StrictStr, Field(pattern=r"^[A-Za-z0-9_-]{16,128}$")]
NonNegInt = Annotated[int, Field(strict=True, ge=0, le=INT64_MAX)]
PositiveInt = Annotated[int, Field(strict=True, ge=1, le=INT64_MAX)]
#: Nanoseconds since the Unix epoch.
TimestampNs = Annotated[int, Field(strict=True, ge=0, le=INT64_MAX)]


def _strict_number(value: Any) -> Any:
    """Accept msgpack ints and floats as floats, nothing else (no bools, no numeric strings)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value  # let the float validator report a clear "valid number" error
    return float(value)


#: Any float, NaN and infinities included (results report NaN when a value does not exist).
AnyFloat = Annotated[float, BeforeValidator(_strict_number), Field(strict=True)]
#: (The constraint before the validator: pydantic then exports it as JSON Schema's
#: ``minimum``; the other order leaks its own ``ge`` into the schema.)
NonNegFiniteFloat = Annotated[
    float, Field(strict=True, ge=0, allow_inf_nan=False), BeforeValidator(_strict_number)
]


def _check_box(value: Any) -> Any:
    """Validate a request box before anything else looks at it, with one clear message.

    A box drawn by an operator is what starts a tracker; an absurd one (NaN, negative or zero
    size, wrong arity) would make the tracker fail later in an obscure way, so it is rejected here
    with the ``invalid_box`` error type that the codec reports as ``ErrorCode.INVALID_BOX``.
    """
    if not isinstance(value, (list, tuple)) or len(value) != 4:
        raise PydanticCustomError(
            BOX_ERROR_TYPE,
            "box must be a list of 4 numbers [x, y, w, h], got {got}",
            {"got": _describe(value)},
        )
    out = []
    for name, item in zip("xywh", value, strict=True):
        if isinstance(item, bool) or not isinstance(item, (int, float)):
            raise PydanticCustomError(
                BOX_ERROR_TYPE,
                "box {name} must be a number, got {got}",
                {"name": name, "got": type(item).__name__},
            )
        number = float(item)
        if not math.isfinite(number):
            raise PydanticCustomError(
                BOX_ERROR_TYPE,
                "box {name} must be finite, got {got}",
                {"name": name, "got": repr(number)},
            )
        out.append(number)
    if not (out[2] > 0 and out[3] > 0):
        raise PydanticCustomError(
            BOX_ERROR_TYPE,
            "box width and height must be > 0, got w={w}, h={h}",
            {"w": repr(out[2]), "h": repr(out[3])},
        )
    if max(abs(number) for number in out) > MAX_BOX_COORD:
        raise PydanticCustomError(
            BOX_ERROR_TYPE,
            "box values must be within +/-{limit} pixels, got {box}",
            {"limit": repr(MAX_BOX_COORD), "box": repr(out)},
        )
    return tuple(out)


def _check_result_box(value: Any) -> Any:
    """A result box is 4 numbers; NaN is allowed (no box when the tracker failed)."""
    if not isinstance(value, (list, tuple)) or len(value) != 4:
        raise PydanticCustomError(
            BOX_ERROR_TYPE,
            "box must be a list of 4 numbers [x, y, w, h], got {got}",
            {"got": _describe(value)},
        )
    return value


def _describe(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return f"{type(value).__name__} of {len(value)} items"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return f"str of {len(value)} characters"
    return type(value).__name__


_BoxSize = Annotated[float, Field(gt=0, le=MAX_BOX_COORD, allow_inf_nan=False)]
_BoxCoord = Annotated[float, Field(ge=-MAX_BOX_COORD, le=MAX_BOX_COORD, allow_inf_nan=False)]

#: ``[x, y, w, h]``, 1-based pixel coordinates of the frame, finite, ``w > 0`` and ``h > 0``.
Box = Annotated[
    tuple[_BoxCoord, _BoxCoord, _BoxSize, _BoxSize],
    BeforeValidator(_check_box),
    Field(
        description=(
            "[x, y, w, h] in the frame's 1-based pixel coordinates: 4 finite numbers, "
            f"w > 0 and h > 0, all within +/-{MAX_BOX_COORD:g} pixels."
        )
    ),
]

#: ``[x, y, w, h]`` reported by the service; NaN when no box exists.
ResultBox = Annotated[
    tuple[AnyFloat, AnyFloat, AnyFloat, AnyFloat],
    BeforeValidator(_check_result_box),
    Field(
        description=(
            "[x, y, w, h] in the frame's 1-based pixel coordinates; may be NaN (msgpack float) "
            "when the tracker has no box."
        )
    ),
]


def _one_override_error(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    """Report a bad override value once, instead of once per member of the union."""
    try:
        return handler(value)
    except ValidationError:
        raise PydanticCustomError(
            "override_value",
            "override values must be a bool, a 64-bit int, a finite float or a string of at "
            "most {limit} characters, got {got}",
            {"limit": MAX_OVERRIDE_STR, "got": _describe(value)},
        ) from None


OverrideKey = Annotated[StrictStr, Field(pattern=OVERRIDE_KEY_PATTERN)]
# StrictBool first: in msgpack (and Python) True is not an integer parameter. Constraints are
# declared on the types (not checked in a validator) so that the JSON Schema states them too.
OverrideValue = Annotated[
    StrictBool
    | Annotated[int, Field(strict=True, ge=-INT64_MAX - 1, le=INT64_MAX)]
    | Annotated[float, Field(strict=True, allow_inf_nan=False)]
    | Annotated[StrictStr, Field(max_length=MAX_OVERRIDE_STR)],
    WrapValidator(_one_override_error),
]


# ---------------------------------------------------------------------------------------------
# Models
# ---------------------------------------------------------------------------------------------


class WireModel(BaseModel):
    """Base of every model: closed (``extra="forbid"``) and immutable (``frozen=True``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class OpenModel(WireModel):
    """Base of the models the service sends to stations: a newer service may add optional
    fields within v1, and decoding ignores the ones it does not know (see the module
    docstring)."""

    model_config = ConfigDict(extra="ignore", frozen=True)


class Message(WireModel):
    """A top-level message: has a wire ``type`` written in the envelope by the codec."""

    #: Wire name of the message kind (the envelope's ``type``).
    type: ClassVar[str]


class Reply(Message):
    """A top-level message the service sends to stations: open for additions like
    :class:`OpenModel`."""

    model_config = ConfigDict(extra="ignore", frozen=True)


class Frame(Message):
    """One image of a stream, put by the ground station on ``<prefix>/streams/<stream>/frames``.

    ``seq`` increases by one per frame of a stream, so the service counts frames lost on the way
    (Zenoh drops frames under congestion by design) instead of guessing. Raw encodings carry their
    size because the bytes alone do not say it; the payload length is checked against it so that
    a truncated raw frame never reaches the tracker.
    """

    type: ClassVar[str] = "frame"

    stream_id: Id
    seq: NonNegInt = Field(description="Frame number, increasing per stream; gaps = lost frames.")
    capture_ts_ns: TimestampNs = Field(description="Capture time, ns since the Unix epoch.")
    encoding: Encoding
    width: PositiveInt | None = Field(
        default=None, description="Image width in pixels; required for bgr8/gray8."
    )
    height: PositiveInt | None = Field(
        default=None, description="Image height in pixels; required for bgr8/gray8."
    )
    payload: bytes = Field(
        strict=True,
        min_length=1,
        description=(
            "The image bytes, sent as msgpack bin (not base64, not a msgpack str): a JPEG/PNG "
            "file, width*height*channels raw bytes (bgr8: 3 channels, gray8: 1), row-major, or "
            "one H.264/H.265 access unit in Annex B form (start codes included)."
        ),
        json_schema_extra={
            "contentEncoding": "binary",
            "contentMediaType": "application/octet-stream",
            "x-msgpack": "bin",
        },
    )

    @model_validator(mode="after")
    def _check_raw_size(self) -> Frame:
        channels = self.encoding.channels
        if channels is None:
            return self
        if self.width is None or self.height is None:
            raise ValueError(f"{self.encoding.value} frames need width and height")
        expected = self.width * self.height * channels
        if len(self.payload) != expected:
            raise ValueError(
                f"{self.encoding.value} payload is {len(self.payload)} bytes, expected "
                f"width*height*{channels} = {expected}"
            )
        return self


class StartRequest(Message):
    """Start a tracking session on a stream, from a box drawn by the operator.

    ``frame_seq`` names the frame the box was drawn on, because the operator drew it on a frame
    that is already some latency old; absent, the box applies to the next frame that arrives.
    """

    type: ClassVar[str] = "start"

    request_id: Id = Field(description="Client-chosen; echoed in the reply.")
    stream_id: Id
    session_id: Id | None = Field(
        default=None,
        description="Client-chosen session id; the service assigns a uuid4 hex when absent.",
    )
    box: Box
    preset: Id = Field(description='Tracker preset, e.g. "arcf-hc".')
    overrides: dict[OverrideKey, OverrideValue] = Field(
        default_factory=dict,
        max_length=MAX_OVERRIDES,
        description=(
            f"Preset parameter overrides: name -> bool/int/float/str, at most {MAX_OVERRIDES}."
        ),
        json_schema_extra={"propertyNames": {"pattern": OVERRIDE_KEY_PATTERN}},
    )
    frame_seq: NonNegInt | None = Field(
        default=None, description="Frame the box was drawn on; absent = the next frame."
    )
    client_id: Id | None = Field(
        default=None,
        description="The station's liveliness token id (<prefix>/clients/<client_id>): when "
        "the token is gone longer than the service's grace period, its sessions end.",
    )


class ReinitRequest(Message):
    """Re-initialise a running session on a new box (the operator corrects a drifted track)."""

    type: ClassVar[str] = "reinit"

    request_id: Id = Field(description="Client-chosen; echoed in the reply.")
    session_id: Id
    box: Box
    frame_seq: NonNegInt | None = Field(
        default=None, description="Frame the box was drawn on; absent = the next frame."
    )
    client_id: Id | None = Field(
        default=None,
        description="The station now holding the session (a restarted station adopting the "
        "sessions it left behind, under its new liveliness token): from now on the session "
        "ends when this token is gone longer than the grace period. Absent: unchanged.",
    )
    control_token: ControlToken | None = Field(
        default=None, description="The session's control token, from its start's ack: "
        "required where the service's session_control is 'owner' (the default).")


class StopRequest(Message):
    """Stop a session and free its tracker."""

    type: ClassVar[str] = "stop"

    request_id: Id = Field(description="Client-chosen; echoed in the reply.")
    session_id: Id
    control_token: ControlToken | None = Field(
        default=None, description="The session's control token, from its start's ack: "
        "required where the service's session_control is 'owner' (the default).")


class StatusRequest(Message):
    """Ask the service what it is running (answered by a ``status`` message)."""

    type: ClassVar[str] = "status_request"

    request_id: Id = Field(description="Client-chosen; echoed in the reply.")
    stream_id: Id | None = Field(
        default=None, description="Only this stream's sessions (e.g. a restarted station "
        "finding the sessions it left behind).")


class Ack(Reply):
    """Positive reply to ``start``/``reinit``/``stop``; carries the ids the request resolved to."""

    type: ClassVar[str] = "ack"

    request_id: Id
    session_id: Id | None = None
    stream_id: Id | None = None
    message: StrictStr
    control_token: ControlToken | None = Field(
        default=None, description="In the ack of a start only: the session's control token, "
        "which its stop and reinit requests carry. The reply goes to the requester alone; "
        "keep it as a credential (a station that restarts and adopts its sessions needs it).")


class ErrorMessage(Reply):
    """Negative reply to a request, or a report about a stream's frames on its ``errors`` key.

    ``code`` is machine-readable; ``message`` is for humans. The ids say what the error is about,
    as far as the service could tell (a malformed request may not even have a request id).
    """

    type: ClassVar[str] = "error"

    code: ErrorCode
    message: StrictStr
    request_id: Id | None = None
    stream_id: Id | None = None
    session_id: Id | None = None
    frame_seq: NonNegInt | None = None


class Result(Reply):
    """The tracker's output for one frame of one session.

    Floats may be NaN (a msgpack float) when a value does not exist, e.g. on ``status="error"``:
    a result is a measurement report, and NaN is more honest than a made-up number. ``dropped``
    counts the frames of the stream the service skipped for this session since its previous result
    (the service keeps up by processing the newest frame, not by queueing).
    """

    type: ClassVar[str] = "result"

    session_id: Id
    stream_id: Id
    frame_seq: NonNegInt
    capture_ts_ns: TimestampNs
    box: ResultBox
    peak: AnyFloat = Field(description="Response map peak.")
    psr: AnyFloat = Field(description="Peak-to-sidelobe ratio of the response map.")
    aberrance: AnyFloat = Field(description="Aberrance of the response map vs the previous one.")
    aberrance_release: AnyFloat = Field(description="Aberrance as computed by the release code.")
    scale: AnyFloat = Field(description="Current scale factor of the target.")
    confidence: AnyFloat | None = Field(
        default=None, description="Estimated probability, in [0, 1], that the box overlaps the "
        "target at all (IoU > 0), from the response's peak, PSR and aberrance (calibrated on "
        "real sequences, see docs/track-state.md). 1 on the frame a box was given. Absent "
        "on results without a box (error, stopped, stale).")
    track_state: TrackState | None = Field(
        default=None, description="tracking, coasting (target probably hidden, the box is a "
        "guess) or lost. Absent on results without a box (error, stopped, stale).")
    reacquired: StrictBool | None = Field(
        default=None, description="True on the frame where a lost track found its target "
        "again (re-acquisition); absent otherwise.")
    status: ResultStatus
    dropped: NonNegInt = Field(
        description="Frames of this stream skipped since the session's previous result."
    )
    message: StrictStr | None = Field(
        default=None, description='Explanation for status "error" (and why a session stopped '
        'or went stale).')
    code: ErrorCode | None = Field(
        default=None, description='Machine-readable reason: always set on status "error" and '
        '"stale" (no_frames), and on "stopped" when the service ended the session by itself.')
    received_ts_ns: TimestampNs = Field(description="When the service received the frame.")
    decode_s: AnyFloat = Field(description="Seconds spent decoding the frame.")
    track_s: AnyFloat = Field(description="Seconds spent in the tracker.")
    published_ts_ns: TimestampNs = Field(description="When the service published this result.")


SessionState = Literal["waiting", "tracking"]


class SessionInfo(OpenModel):
    """One running session, as listed in ``status`` (not a top-level message)."""

    session_id: Id
    stream_id: Id
    preset: Id
    frames: NonNegInt | None = Field(
        default=None, description="Frames processed by this session so far (null: run by "
        "another instance, which knows).")
    state: SessionState | None = Field(
        default=None, description="waiting: for the frame its box applies to; tracking: "
        "producing results; null: run by another instance.")
    last_seq: NonNegInt | None = Field(default=None, description="Frame of its last result.")
    last_result_ts_ns: TimestampNs | None = Field(
        default=None, description="When its last result was published.")
    client_id: Id | None = Field(default=None, description="The station that started it.")


class SessionSpec(Message):
    """What a session is, as the instances replicate it on ``<prefix>/registry/<session>``.

    Enough to start the session again elsewhere: when its instance dies, the new owner of the
    stream resumes it from ``last_box`` on the frame after ``last_seq`` (the instances follow
    every result); without a published result yet, from ``box`` on ``frame_seq``.
    """

    type: ClassVar[str] = "session_spec"

    session_id: Id
    stream_id: Id
    preset: Id
    overrides: dict[OverrideKey, OverrideValue] = Field(default_factory=dict,
                                                        max_length=MAX_OVERRIDES)
    box: Box
    frame_seq: NonNegInt | None = None
    client_id: Id | None = None
    control_token_sha256: Annotated[StrictStr, Field(pattern=r"^[0-9a-f]{64}$")] | None = Field(
        default=None, description="SHA-256 of the session's control token (hex), so that any "
        "instance can check a stop or reinit; the token itself is never replicated.")
    last_seq: NonNegInt | None = Field(default=None, description="Frame of the last result.")
    last_box: Box | None = Field(default=None, description="Box of the last result.")


#: ``last_boxes`` lists at most this many sessions (those of one worker: ``max_sessions``
#: bounds them far below)
MAX_LAST_BOXES = 4096


class LastBox(WireModel):
    """One session's last published box (inside ``last_boxes``)."""

    session_id: Id
    frame_seq: NonNegInt
    box: Box


class LastBoxes(Message):
    """The last box of every session one worker runs, put on
    ``<prefix>/boxes/<instance>/<worker>`` at a bounded rate (``last_box_period_ms``) when one
    changed: what another instance resumes a session from if this one dies. Instances follow
    these instead of every result, so what each receives to take over grows with the
    sessions, not with the frames they track."""

    type: ClassVar[str] = "last_boxes"

    instance_id: Id
    worker: NonNegInt
    boxes: list[LastBox] = Field(max_length=MAX_LAST_BOXES)


class Status(Reply):
    """Reply to ``status_request``: what the service runs (every instance, when several share
    the streams; ``instance_id`` is the one that answered)."""

    type: ClassVar[str] = "status"

    request_id: Id
    instance_id: Id
    version: StrictStr = Field(max_length=64, description="Version of the service software.")
    workers: NonNegInt = Field(description="Live worker processes.")
    streams: list[Id] = Field(description="Streams with at least one session.")
    sessions: list[SessionInfo]
    uptime_s: NonNegFiniteFloat
    instances: list[Id] = Field(default_factory=list,
                                description="Live service instances sharing the streams.")


class PresetsRequest(Message):
    """Ask the service which presets it runs and what each override accepts; with a
    ``preset``, also whether a ``start`` with that preset and ``overrides`` would be accepted
    (checked as a start is, nothing started: the reply's ``refused``)."""

    type: ClassVar[str] = "presets_request"

    request_id: Id = Field(description="Client-chosen; echoed in the reply.")
    preset: Id | None = Field(
        default=None, description="A preset to check, as a start would name it.")
    overrides: dict[OverrideKey, OverrideValue] = Field(
        default_factory=dict,
        max_length=MAX_OVERRIDES,
        description="With ``preset``: the overrides to check with it.",
        json_schema_extra={"propertyNames": {"pattern": OVERRIDE_KEY_PATTERN}},
    )


class ParameterInfo(OpenModel):
    """One override a ``start`` may carry (not a top-level message)."""

    name: OverrideKey
    kind: Literal["bool", "int", "float", "str"]
    minimum: float | None = Field(default=None, description="Inclusive lower bound.")
    maximum: float | None = Field(default=None, description="Inclusive upper bound.")
    choices: list[StrictStr] | None = Field(default=None, description="The allowed values.")


class PresetInfo(OpenModel):
    """One preset and the value of each override in it (not a top-level message)."""

    name: Id
    values: dict[OverrideKey, OverrideValue]


class Presets(Reply):
    """Reply to ``presets_request``: the presets and every override with its declared type and
    range, as the service enforces them (a value outside is refused, ``invalid_parameter``)."""

    type: ClassVar[str] = "presets"

    request_id: Id
    presets: list[PresetInfo]
    parameters: list[ParameterInfo]
    refused: ErrorCode | None = Field(
        default=None, description="The request named a preset: the code a start with it and "
        "its overrides would be refused with (absent: it would be accepted).")
    refusal: str | None = Field(default=None, description="Why, with ``refused``.")


#: Every top-level message model by wire type, in the order of the design document.
MESSAGE_TYPES: dict[str, type[Message]] = {
    model.type: model
    for model in (
        Frame,
        StartRequest,
        ReinitRequest,
        StopRequest,
        StatusRequest,
        PresetsRequest,
        Ack,
        ErrorMessage,
        Result,
        Status,
        Presets,
        SessionSpec,
        LastBoxes,
    )
}
