"""Property-based fuzzing (hypothesis) of everything that reads input from the network or a
caller: the message decoder, the image header check and decoder, and the box and frame
validators. Whatever the input, each returns a value or raises its documented error; nothing
else escapes. Every CI run executes 1,000 cases per fast property (six of them) and 200 per
slow one (three): 6,600 cases in all. (It found one crash: OpenCV asserts on an empty buffer
instead of failing; ``decode_image`` now reports it as a decode error.)"""

from __future__ import annotations

import math
from types import SimpleNamespace

import cv2
import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import arcf
from arcf import ARCFError
from arcf.client.media.encodings import decode_image
from arcf.client.media.headers import image_size
from arcf.schemas import (
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    Frame,
    Message,
    SchemaError,
    StartRequest,
    decode,
    encode,
)
from arcf.types import validate_box, validate_frame

FAST = settings(max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SLOW = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

ANY_MESSAGE = tuple(MESSAGE_TYPES.values())

msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=80)
    | st.binary(max_size=200),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=12), inner,
                                                                max_size=6),
    max_leaves=20,
)
field_names = st.sampled_from(sorted({name for model in ANY_MESSAGE
                                      for name in model.model_fields})) | st.text(max_size=12)


def _decodes_or_refuses(data: bytes) -> None:
    try:
        message = decode(data, expected=ANY_MESSAGE, max_payload=64 * 1024)
    except SchemaError as exc:
        assert exc.code is not None and str(exc)
        return
    assert isinstance(message, Message)


@FAST
@given(st.binary(max_size=512))
def test_random_bytes_never_crash_the_decoder(data: bytes) -> None:
    _decodes_or_refuses(data)


# fewer than FAST: generating maps is the slow part, and fuzz/ (.ci/run) covers the codec
# with coverage guidance besides
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@pytest.mark.slow
@given(st.sampled_from([*MESSAGE_TYPES, "nope", ""]) | st.text(max_size=10),
       st.sampled_from([SCHEMA_VERSION, 0, 2, -1, "1", None]),
       st.dictionaries(field_names, msgpack_values, max_size=10))
def test_random_maps_with_plausible_envelopes(kind: str, version: object,
                                              fields: dict[str, object]) -> None:
    _decodes_or_refuses(msgpack.packb({"v": version, "type": kind, **fields},
                                      use_bin_type=True))


def _valid_messages() -> list[bytes]:
    frame = Frame(stream_id="cam-1", seq=7, capture_ts_ns=1, encoding="jpeg",
                  payload=b"\xff\xd8" + bytes(300))
    start = StartRequest(request_id="r1", stream_id="cam-1", box=(1, 2, 30, 40),
                         preset="arcf-hc", overrides={"admm_iterations": 2})
    return [encode(frame), encode(start)]


@FAST
@given(st.sampled_from(_valid_messages()), st.data())
def test_truncated_and_corrupted_messages(message: bytes, data: st.DataObject) -> None:
    cut = data.draw(st.integers(min_value=0, max_value=len(message) - 1))
    _decodes_or_refuses(message[:cut])  # truncated: refused, never a partial message
    flips = data.draw(st.lists(st.tuples(st.integers(0, len(message) - 1),
                                         st.integers(0, 255)), max_size=4))
    corrupted = bytearray(message)
    for i, b in flips:
        corrupted[i] = b
    _decodes_or_refuses(bytes(corrupted))


@SLOW
@given(st.integers(min_value=64 * 1024 + 1, max_value=2**32 - 1), st.binary(max_size=64))
def test_huge_declared_sizes_are_refused_without_allocating(declared: int, tail: bytes) -> None:
    # a bin32 payload header that promises far more bytes than follow (or than allowed)
    head = msgpack.packb({"v": SCHEMA_VERSION, "type": "frame", "stream_id": "s", "seq": 0,
                          "capture_ts_ns": 1, "encoding": "jpeg"}, use_bin_type=True)
    body = bytearray(head)
    body[0] += 1  # one more map entry...
    data = bytes(body) + msgpack.packb("payload") + b"\xc6" + declared.to_bytes(4, "big") + tail
    _decodes_or_refuses(data)


_rng = np.random.default_rng(1)
_JPEG = cv2.imencode(".jpg", _rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))[1].tobytes()
_PNG = cv2.imencode(".png", _rng.integers(0, 255, (30, 40), dtype=np.uint8))[1].tobytes()


@FAST
@given(st.sampled_from([("jpeg", _JPEG), ("png", _PNG)]), st.data())
def test_truncated_and_corrupted_images_never_crash_the_decoder(
        image: tuple[str, bytes], data: st.DataObject) -> None:
    encoding, payload = image
    cut = data.draw(st.integers(min_value=0, max_value=len(payload)))
    flips = data.draw(st.lists(st.tuples(st.integers(0, len(payload) - 1),
                                         st.integers(0, 255)), max_size=6))
    corrupted = bytearray(payload[:cut])
    for i, b in flips:
        if i < len(corrupted):
            corrupted[i] = b
    limit = data.draw(st.sampled_from([None, 64 * 48, 100]))
    frame = SimpleNamespace(encoding=encoding, payload=bytes(corrupted), width=None, height=None)
    out, problem = decode_image(frame, limit)
    if out is None:
        assert problem is None or problem[0] in ("decode_error", "image_too_large")
    else:
        assert out.dtype == np.uint8 and out.ndim in (2, 3)
        size = image_size(bytes(corrupted))
        if limit is not None:  # what was decoded was declared within the limit
            assert size is not None and size[0] * size[1] <= limit


@FAST
@given(st.binary(max_size=64))
def test_header_reader_on_random_bytes(data: bytes) -> None:
    size = image_size(b"\xff\xd8" + data)
    assert size is None or (0 <= size[0] < 2**16 and 0 <= size[1] < 2**16)
    size = image_size(b"\x89PNG\r\n\x1a\n" + data)
    assert size is None or (0 <= size[0] < 2**32 and 0 <= size[1] < 2**32)


numbers = st.floats(allow_nan=True, allow_infinity=True) | st.integers(-10**12, 10**12)


@FAST
@given(st.lists(numbers, min_size=0, max_size=6) | st.text(max_size=8) | st.none())
def test_absurd_boxes_are_refused_clearly(box: object) -> None:
    try:
        x, y, w, h = validate_box(box, (480, 640))
    except ARCFError as exc:
        assert str(exc)
        return
    assert all(math.isfinite(v) for v in (x, y, w, h)) and w >= 1 and h >= 1


@SLOW
@given(st.tuples(numbers, numbers, numbers, numbers))
def test_tracker_init_with_any_box_tracks_or_refuses(box: tuple[float, ...]) -> None:
    frame = cv2.GaussianBlur(_rng.integers(0, 255, (60, 80, 3), dtype=np.uint8), (0, 0), 2)
    tracker = arcf.create_tracker("bacf")
    try:
        result = tracker.init(frame, box)
    except ARCFError:
        assert not tracker.initialized
        return
    assert all(math.isfinite(v) for v in result.box)
    assert all(math.isfinite(v) for v in tracker.update(frame).box)


@SLOW
@given(st.sampled_from([np.uint8, np.float32, np.int16, np.bool_]),
       st.lists(st.integers(0, 5), min_size=0, max_size=4))
def test_absurd_frames_are_refused_clearly(dtype: type, shape: list[int]) -> None:
    frame = np.zeros(shape, dtype=dtype)
    try:
        validate_frame(frame)
    except ARCFError as exc:
        assert str(exc)
        return
    assert frame.dtype == np.uint8 and frame.shape[0] >= 2 and frame.shape[1] >= 2
