"""msgpack encoding and defensive decoding of wire messages.

A message on the wire is one msgpack map: ``{"v": 1, "type": "<kind>", <fields>...}`` with the
envelope keys first, bytes as msgpack ``bin`` and ``None`` fields omitted. :func:`decode` never
trusts its input: every way a payload can be wrong ends in a :class:`SchemaError` (a
``ValueError``) whose ``code`` is the :class:`~arcf.schemas.messages.ErrorCode` to report to the
peer, and whose ``request_id``/``stream_id``/``session_id``/``frame_seq`` carry whatever ids
could be read from the bad message, so the service can still address its error reply.

Frames are the hot path (a 100 KB JPEG at 30 fps from many streams), so the payload is copied as
little as msgpack allows: once by :func:`encode` (into the output buffer) and once by
:func:`decode` (out of the input buffer into the ``bytes`` object the model keeps).
"""

from __future__ import annotations

import json
import math
import re
import threading
from enum import Enum
from typing import Any, TypeVar, overload

import msgpack
from pydantic import BaseModel, ValidationError

from .messages import (
    BOX_ERROR_TYPE,
    ID_PATTERN,
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    ErrorCode,
    ErrorMessage,
    Message,
)

__all__ = [
    "DEFAULT_MAX_PAYLOAD",
    "MAX_ARRAY_LEN",
    "MAX_MAP_LEN",
    "MAX_STR_LEN",
    "InvalidMessage",
    "MalformedMessage",
    "OversizedPayload",
    "SchemaError",
    "UnexpectedType",
    "UnknownType",
    "UnsupportedVersion",
    "decode",
    "encode",
    "from_json",
    "to_json",
]

#: Largest ``bin`` (frame payload) :func:`decode` accepts by default: 16 MiB, a 4K raw BGR frame
#: is ~25 MB and should be compressed; a JPEG of any sane camera fits.
DEFAULT_MAX_PAYLOAD = 16 * 1024 * 1024
#: Longest msgpack ``str``: ids are 64 characters, messages are sentences.
MAX_STR_LEN = 64 * 1024
#: Longest msgpack array: boxes have 4 items; ``status`` lists streams and sessions.
MAX_ARRAY_LEN = 10_000
#: Largest msgpack map: messages have about 20 keys, ``overrides`` at most 32.
MAX_MAP_LEN = 1_024
#: Bytes a message may have beyond ``max_payload`` before it is rejected unparsed.
_ENVELOPE_ALLOWANCE = 1024 * 1024
#: Validation errors spelled out in an ``InvalidMessage`` message (all are in ``.errors``).
_MAX_LISTED_ERRORS = 8

_ID_RE = re.compile(ID_PATTERN)
_ENVELOPE = ("v", "type")
_M = TypeVar("_M", bound=Message)


class SchemaError(ValueError):
    """A message that cannot be accepted; ``code`` is the error code to send back.

    The optional ids are read best-effort from the offending message (only when they are valid
    ids), so that an error reply can name the request, stream or session it is about.
    """

    code: ErrorCode = ErrorCode.MALFORMED_MESSAGE

    def __init__(
        self,
        message: str,
        *,
        code: ErrorCode | None = None,
        msg_type: str | None = None,
        request_id: str | None = None,
        stream_id: str | None = None,
        session_id: str | None = None,
        frame_seq: int | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        if code is not None:
            self.code = code
        self.msg_type = msg_type
        self.request_id = request_id
        self.stream_id = stream_id
        self.session_id = session_id
        self.frame_seq = frame_seq

    def to_error_message(self) -> ErrorMessage:
        """The ``error`` message that reports this failure to the peer."""
        return ErrorMessage(
            code=self.code,
            message=self.message,
            request_id=self.request_id,
            stream_id=self.stream_id,
            session_id=self.session_id,
            frame_seq=self.frame_seq,
        )


class MalformedMessage(SchemaError):
    """Not msgpack, not a map, trailing bytes, a limit exceeded, or no valid ``v``/``type``."""

    code = ErrorCode.MALFORMED_MESSAGE


class OversizedPayload(SchemaError):
    """A ``bin`` (frame payload) or the whole message is larger than ``max_payload`` allows."""

    code = ErrorCode.OVERSIZED_PAYLOAD


class UnsupportedVersion(SchemaError):
    """The envelope's ``v`` is not :data:`~arcf.schemas.messages.SCHEMA_VERSION`."""

    code = ErrorCode.UNSUPPORTED_VERSION


class UnknownType(SchemaError):
    """The envelope's ``type`` names no message kind of this version."""

    code = ErrorCode.UNKNOWN_TYPE


class UnexpectedType(SchemaError):
    """A valid kind of message, but not one accepted where it was sent (e.g. a frame on control)."""

    code = ErrorCode.INVALID_REQUEST


class InvalidMessage(SchemaError):
    """Fields failed validation; ``code`` is ``invalid_box`` when only the box is wrong.

    ``errors`` holds pydantic's error list (without the offending input values, which may be
    large or sensitive), for programs; the message lists the failing fields, for humans.
    """

    code = ErrorCode.INVALID_REQUEST

    def __init__(self, message: str, *, errors: list[dict[str, Any]], **kwargs: Any) -> None:
        super().__init__(message, **kwargs)
        self.errors = errors


# ---------------------------------------------------------------------------------------------
# Encoding
# ---------------------------------------------------------------------------------------------


#: ``bytes`` fields at least this long are appended to the output instead of going through
#: ``msgpack.packb``, which would copy them twice (into its buffer, then into the result).
_BIG_BIN = 4096
_FIELD_NAMES: dict[type[BaseModel], tuple[str, ...]] = {}
_local = threading.local()
#: Field value types msgpack packs as they are (exact types: enums are str subclasses).
_AS_IS = frozenset((str, int, float, bool, bytes, tuple, dict))


def _plain(value: Any) -> Any:
    """A model field value as msgpack-ready data (enums as their values, models as maps)."""
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, BaseModel):
        return _fields(value, {})
    if isinstance(value, list):
        return [_plain(item) for item in value]
    return value  # str, int, float, bytes, tuple of floats, dict of scalars


def _fields(model: BaseModel, out: dict[str, Any]) -> dict[str, Any]:
    """Add the non-``None`` fields of ``model`` to ``out``, in declaration order."""
    cls = type(model)
    names = _FIELD_NAMES.get(cls)
    if names is None:
        names = _FIELD_NAMES.setdefault(cls, tuple(cls.model_fields))
    values = model.__dict__
    for name in names:
        value = values[name]
        if value is not None:
            out[name] = value if type(value) in _AS_IS else _plain(value)
    return out


def _map_header(count: int) -> bytes:
    if count < 16:
        return bytes((0x80 | count,))
    if count < 0x10000:
        return b"\xde" + count.to_bytes(2, "big")
    return b"\xdf" + count.to_bytes(4, "big")


def _map_header_size(first: int) -> int:
    return 1 if 0x80 <= first <= 0x8F else 3 if first == 0xDE else 5


def _bin_header(size: int) -> bytes:
    if size < 0x100:
        return bytes((0xC4, size))
    if size < 0x10000:
        return b"\xc5" + size.to_bytes(2, "big")
    if size < 0x100000000:
        return b"\xc6" + size.to_bytes(4, "big")
    raise ValueError(f"a bytes field of {size} bytes is too large for msgpack (4 GiB max)")


def _packer() -> msgpack.Packer:
    """This thread's Packer: ``msgpack.packb`` builds (and allocates a buffer for) a new one per
    call, which costs about a microsecond; a Packer is not thread-safe, hence one per thread."""
    try:
        return _local.packer
    except AttributeError:
        packer = _local.packer = msgpack.Packer(use_bin_type=True)
        return packer


def encode(model: Message) -> bytes:
    """Encode a message as a msgpack map, ``v`` and ``type`` first, ``None`` fields omitted.

    Fields are read straight from the (already validated, immutable) model rather than through
    ``model_dump``; ``bytes`` go out as msgpack ``bin`` (``use_bin_type=True``). Large ``bytes``
    fields (a frame's payload, the last field of ``Frame``) are written after the other fields
    with a hand-made ``bin`` header and joined once, so the payload is copied exactly once; the
    output is byte-for-byte what ``msgpack.packb(..., use_bin_type=True)`` gives for the same map.
    """
    if not isinstance(model, Message):
        raise TypeError(f"encode() needs a schemas message model, got {type(model).__name__}")
    out = _fields(model, {"v": SCHEMA_VERSION, "type": model.type})
    packer = _packer()
    big = [name for name, value in out.items() if type(value) is bytes and len(value) >= _BIG_BIN]
    if not big:
        return packer.pack(out)
    tail = [(name, out.pop(name)) for name in big]
    head = packer.pack(out)
    parts: list[bytes | memoryview] = [
        _map_header(len(out) + len(tail)),
        memoryview(head)[_map_header_size(head[0]) :],
    ]
    for name, value in tail:
        parts += (packer.pack(name), _bin_header(len(value)), value)
    return b"".join(parts)


def to_json(model: Message) -> bytes:
    """A message as JSON, in the same form as on the wire (``v`` and ``type`` first, ``None``
    fields omitted): what the exported JSON Schema of its type validates. JSON has no NaN:
    a non-finite number (the box of a result with no box) is written ``null``, as every JSON
    reader takes it. For records of messages without ``bytes`` fields (a recording's
    results); a frame's payload has no JSON form."""
    if not isinstance(model, Message):
        raise TypeError(f"to_json() needs a schemas message model, got {type(model).__name__}")
    return json.dumps(_finite(_fields(model, {"v": SCHEMA_VERSION, "type": model.type})),
                      allow_nan=False).encode()


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


# ---------------------------------------------------------------------------------------------
# Decoding
# ---------------------------------------------------------------------------------------------


def _ids(obj: dict[Any, Any]) -> dict[str, Any]:
    """Ids readable from a bad message, for the error reply; invalid ones are left out."""
    found: dict[str, Any] = {}
    for key in ("request_id", "stream_id", "session_id"):
        value = obj.get(key)
        if isinstance(value, str) and _ID_RE.match(value):
            found[key] = value
    seq = obj.get("frame_seq", obj.get("seq"))
    if type(seq) is int and 0 <= seq < 2**63:
        found["frame_seq"] = seq
    return found


def _clip(text: str, limit: int = 64) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _short(value: Any, limit: int = 64) -> str:
    return _clip(repr(value), limit)


def _field_code(err: dict[str, Any]) -> ErrorCode:
    """The code of one validation error: a box gets ``invalid_box``, an override
    ``invalid_parameter`` (as a value the presets refuse), anything else ``invalid_request``."""
    field = err["loc"][0] if err["loc"] else None
    if field == "box" or err["type"] == BOX_ERROR_TYPE:
        return ErrorCode.INVALID_BOX
    if field == "overrides":
        return ErrorCode.INVALID_PARAMETER
    return ErrorCode.INVALID_REQUEST


def _describe_errors(msg_type: str, exc: ValidationError
                     ) -> tuple[str, list[dict[str, Any]], ErrorCode]:
    """The message, the errors and their code: the field's own code when every error is in
    one kind of field (the box, the overrides), else ``invalid_request``."""
    errors: list[dict[str, Any]] = [
        dict(e) for e in exc.errors(include_url=False, include_input=False, include_context=False)]
    parts = []
    codes = {_field_code(err) for err in errors}
    code = codes.pop() if len(codes) == 1 else ErrorCode.INVALID_REQUEST
    for index, err in enumerate(errors):
        if index == _MAX_LISTED_ERRORS:
            parts.append(f"and {len(errors) - index} more")
            continue
        if index > _MAX_LISTED_ERRORS:
            continue
        # locations may hold peer-chosen keys: keep the message short whatever was sent
        loc = ".".join(_clip(str(part)) for part in err["loc"]) or msg_type
        if err["type"] == "extra_forbidden":
            text = "unexpected field (not in the contract)"
        elif err["type"] == "missing":
            text = "required field missing"
        else:
            text = err["msg"].removeprefix("Value error, ")
        parts.append(f"{loc}: {text}")
    return f"invalid {msg_type} message: " + "; ".join(parts), errors, code


@overload
def decode(
    data: bytes | bytearray | memoryview,
    expected: type[_M],
    *,
    max_payload: int = ...,
) -> _M: ...


@overload
def decode(
    data: bytes | bytearray | memoryview,
    expected: tuple[type[Message], ...] | None = None,
    *,
    max_payload: int = ...,
) -> Message: ...


def decode(
    data: bytes | bytearray | memoryview,
    expected: type[Message] | tuple[type[Message], ...] | None = None,
    *,
    max_payload: int = DEFAULT_MAX_PAYLOAD,
) -> Message:
    """Decode and validate one message; raise a :class:`SchemaError` subclass if it is bad.

    ``expected`` restricts the accepted kinds (one model class or a tuple of them): anything else
    raises :class:`UnexpectedType` before field validation. ``max_payload`` bounds every msgpack
    ``bin``; a larger one raises :class:`OversizedPayload` before it is copied. The order of the
    checks is: size, msgpack, map, ``v``, ``type``, ``expected``, fields.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"decode() needs bytes, got {type(data).__name__}")
    size = memoryview(data).nbytes if isinstance(data, memoryview) else len(data)
    if size > max_payload + _ENVELOPE_ALLOWANCE:
        raise OversizedPayload(
            f"message of {size} bytes exceeds the {max_payload}-byte payload limit"
        )
    try:
        obj = msgpack.unpackb(
            data,
            raw=False,
            strict_map_key=True,
            max_bin_len=max_payload,
            max_str_len=MAX_STR_LEN,
            max_array_len=MAX_ARRAY_LEN,
            max_map_len=MAX_MAP_LEN,
            max_ext_len=0,
        )
    except (ValueError, TypeError) as exc:  # ExtraData, FormatError, StackError, limits, UTF-8
        text = str(exc) or type(exc).__name__
        if "max_bin_len" in text:
            raise OversizedPayload(
                f"payload exceeds the {max_payload}-byte limit ({text})"
            ) from None
        raise MalformedMessage(f"not a single valid msgpack value: {text}") from None
    if not isinstance(obj, dict):
        raise MalformedMessage(f"message must be a msgpack map, got {type(obj).__name__}")
    return _validate(obj, expected)


def from_json(data: bytes | str, expected: type[Message] | tuple[type[Message], ...] | None = None,
              ) -> Message:
    """Decode and validate one message written as JSON (:func:`to_json`'s form, as a person
    types it for Zenoh's command-line tools): the same checks and errors as :func:`decode`
    after the parse. ``null`` stands for NaN in a number field that allows it (a box); JSON
    has no ``bytes``, so a frame cannot be written this way."""
    size = len(data)
    if size > MAX_STR_LEN:
        raise OversizedPayload(f"JSON message of {size} bytes exceeds {MAX_STR_LEN} bytes")
    try:
        obj = json.loads(data)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, bad UTF-8, too deep
        raise MalformedMessage(f"not a single valid JSON value: {_clip(str(exc))}") from None
    if not isinstance(obj, dict):
        raise MalformedMessage(f"message must be a JSON object, got {type(obj).__name__}")
    return _validate(obj, expected)


def _validate(obj: dict[Any, Any],
              expected: type[Message] | tuple[type[Message], ...] | None) -> Message:
    """A parsed message's envelope, kind and fields checked (:func:`decode`'s order)."""
    if "v" not in obj or "type" not in obj:
        missing = " and ".join(repr(key) for key in _ENVELOPE if key not in obj)
        raise MalformedMessage(f"message has no {missing} envelope key", **_ids(obj))
    version = obj.pop("v")
    if type(version) is not int:
        raise MalformedMessage(f"'v' must be an integer, got {_short(version)}", **_ids(obj))
    if version != SCHEMA_VERSION:
        raise UnsupportedVersion(
            f"schema version {version} is not supported (this side speaks v{SCHEMA_VERSION})",
            **_ids(obj),
        )
    msg_type = obj.pop("type")
    if not isinstance(msg_type, str):
        raise MalformedMessage(f"'type' must be a string, got {_short(msg_type)}", **_ids(obj))
    model = MESSAGE_TYPES.get(msg_type)
    if model is None:
        raise UnknownType(
            f"unknown message type {_short(msg_type)}; known: {', '.join(MESSAGE_TYPES)}",
            msg_type=msg_type if len(msg_type) <= 64 else None,
            **_ids(obj),
        )
    if expected is not None and not issubclass(model, expected):
        wanted = expected if isinstance(expected, tuple) else (expected,)
        raise UnexpectedType(
            f"a {msg_type!r} message is not accepted here; expected "
            + " or ".join(repr(getattr(cls, "type", cls.__name__)) for cls in wanted),
            msg_type=msg_type,
            **_ids(obj),
        )
    try:
        return model.model_validate(obj)
    except ValidationError as exc:
        message, errors, code = _describe_errors(msg_type, exc)
        raise InvalidMessage(
            message,
            errors=errors,
            code=code,
            msg_type=msg_type,
            **_ids(obj),
        ) from None
