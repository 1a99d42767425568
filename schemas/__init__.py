"""Wire contract of the ARCF tracking service: messages, msgpack codec and Zenoh keys.

The design is ``docs/wire-contract.md``. The pydantic models here are its source of truth;
``schemas/json`` holds the JSON Schemas generated from them (``python -m arcf.schemas.export``) for
clients in other languages.

>>> from arcf.schemas import Frame, KeySpace, decode, encode
>>> frame = Frame(stream_id="cam1", seq=0, capture_ts_ns=0, encoding="jpeg", payload=b"...")
>>> decode(encode(frame), Frame) == frame
True
"""

# The package offers its modules' names, each listed once in its module's ``__all__`` (which the
# API reference reads too), less the codec's msgpack limits and the messages' validation
# internals: those stay reachable only through their module.
from . import codec, keys, messages
from .codec import *  # noqa: F403
from .keys import *  # noqa: F403
from .messages import *  # noqa: F403

_MODULE_ONLY = {"MAX_ARRAY_LEN", "MAX_MAP_LEN", "MAX_STR_LEN",  # codec
                "BOX_ERROR_TYPE", "INT64_MAX", "OVERRIDE_KEY_PATTERN"}  # messages
__all__ = sorted({*codec.__all__, *keys.__all__, *messages.__all__} - _MODULE_ONLY)
