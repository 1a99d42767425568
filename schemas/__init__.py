"""Wire contract of the ARCF tracking service: messages, msgpack codec and Zenoh keys.

The design is ``docs/wire-contract.md``. The pydantic models here are its source of truth;
``schemas/json`` holds the JSON Schemas generated from them (``python -m schemas.export``) for
clients in other languages.

>>> from schemas import Frame, KeySpace, decode, encode
>>> frame = Frame(stream_id="cam1", seq=0, capture_ts_ns=0, encoding="jpeg", payload=b"...")
>>> decode(encode(frame), Frame) == frame
True
"""

from .codec import (
    DEFAULT_MAX_PAYLOAD,
    InvalidMessage,
    MalformedMessage,
    OversizedPayload,
    SchemaError,
    UnexpectedType,
    UnknownType,
    UnsupportedVersion,
    decode,
    encode,
)
from .keys import DEFAULT_PREFIX, KEY_ROUTES, InvalidKey, KeyRoute, KeySpace, check_id, is_valid_id
from .messages import (
    ID_PATTERN,
    MAX_BOX_COORD,
    MAX_OVERRIDES,
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    Ack,
    Box,
    Encoding,
    ErrorCode,
    ErrorMessage,
    Frame,
    Message,
    ParameterInfo,
    PresetInfo,
    Presets,
    PresetsRequest,
    ReinitRequest,
    Result,
    ResultBox,
    ResultStatus,
    SessionInfo,
    SessionSpec,
    StartRequest,
    Status,
    StatusRequest,
    StopRequest,
    WireModel,
)

__all__ = [
    "DEFAULT_MAX_PAYLOAD",
    "DEFAULT_PREFIX",
    "ID_PATTERN",
    "KEY_ROUTES",
    "MAX_BOX_COORD",
    "MAX_OVERRIDES",
    "MESSAGE_TYPES",
    "SCHEMA_VERSION",
    "Ack",
    "Box",
    "Encoding",
    "ErrorCode",
    "ErrorMessage",
    "Frame",
    "InvalidKey",
    "InvalidMessage",
    "KeyRoute",
    "KeySpace",
    "MalformedMessage",
    "Message",
    "OversizedPayload",
    "ParameterInfo",
    "PresetInfo",
    "Presets",
    "PresetsRequest",
    "ReinitRequest",
    "Result",
    "ResultBox",
    "ResultStatus",
    "SchemaError",
    "SessionInfo",
    "SessionSpec",
    "StartRequest",
    "Status",
    "StatusRequest",
    "StopRequest",
    "UnexpectedType",
    "UnknownType",
    "UnsupportedVersion",
    "WireModel",
    "check_id",
    "decode",
    "encode",
    "is_valid_id",
]
