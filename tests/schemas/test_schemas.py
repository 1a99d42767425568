"""The wire contract (`schemas`): models, msgpack codec, key expressions and JSON Schema export."""

from __future__ import annotations

import math
import os
import re
import threading
from pathlib import Path
from typing import Any

import msgpack
import pytest
from pydantic import ValidationError

from arcf.schemas import (
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    Ack,
    Encoding,
    ErrorCode,
    ErrorMessage,
    Frame,
    InvalidKey,
    InvalidMessage,
    KeySpace,
    LastBox,
    LastBoxes,
    MalformedMessage,
    Message,
    OversizedPayload,
    ParameterInfo,
    PresetInfo,
    Presets,
    PresetsRequest,
    ReinitRequest,
    Result,
    ResultStatus,
    SchemaError,
    SessionInfo,
    SessionSpec,
    StartRequest,
    Status,
    StatusRequest,
    StopRequest,
    TrackState,
    UnexpectedType,
    UnknownType,
    UnsupportedVersion,
    decode,
    encode,
    export,
)

NAN = float("nan")


def samples() -> dict[str, Message]:
    """One valid instance of every message kind, optional fields mostly filled in."""
    return {
        "frame": Frame(
            stream_id="cam1",
            seq=7,
            capture_ts_ns=1_700_000_000_123_456_789,
            encoding=Encoding.JPEG,
            width=640,
            height=480,
            payload=b"\xff\xd8\xff\xe0" + bytes(range(256)) * 4,
        ),
        "start": StartRequest(
            request_id="req-1",
            stream_id="cam1",
            session_id="s1",
            box=(10, 20.5, 30, 40),
            preset="arcf-hc",
            overrides={"gamma": 0.5, "admm_iterations": 3, "round_translation": True, "x": "y"},
            frame_seq=5,
        ),
        "reinit": ReinitRequest(request_id="req-2", session_id="s1", box=[1, 1, 2.5, 3.5]),
        "stop": StopRequest(request_id="req-3", session_id="s1"),
        "status_request": StatusRequest(request_id="req-4"),
        "presets_request": PresetsRequest(request_id="req-5"),
        "presets": Presets(
            request_id="req-5",
            presets=[PresetInfo(name="arcf-h", values={"gamma": 0.71, "sampling": "pyramid"})],
            parameters=[ParameterInfo(name="gamma", kind="float", minimum=0.0, maximum=100.0),
                        ParameterInfo(name="sampling", kind="str",
                                      choices=["release", "pyramid"])],
        ),
        "ack": Ack(request_id="req-1", session_id="s1", stream_id="cam1", message="started"),
        "error": ErrorMessage(
            code=ErrorCode.NO_SESSION, message="no session on cam1", stream_id="cam1", frame_seq=3
        ),
        "result": Result(
            session_id="s1",
            stream_id="cam1",
            frame_seq=8,
            capture_ts_ns=1_700_000_000_123_456_789,
            box=(11.25, 21.0, 30.0, 40.0),
            peak=0.61,
            psr=12.5,
            aberrance=0.02,
            aberrance_release=0.03,
            scale=1.01,
            status=ResultStatus.TRACKING,
            dropped=0,
            received_ts_ns=1_700_000_000_130_000_000,
            decode_s=0.002,
            track_s=0.011,
            published_ts_ns=1_700_000_000_145_000_000,
        ),
        "status": Status(
            request_id="req-4",
            instance_id="host-a.1",
            version="0.1.0",
            workers=2,
            streams=["cam1"],
            sessions=[SessionInfo(session_id="s1", stream_id="cam1", preset="arcf-hc", frames=9)],
            uptime_s=12.5,
            instances=["host-a.1", "host-b.1"],
        ),
        "session_spec": SessionSpec(
            session_id="s1",
            stream_id="cam1",
            preset="arcf-hc",
            overrides={"admm_iterations": 3},
            box=(120.0, 80.0, 40.0, 30.0),
            frame_seq=0,
            last_seq=41,
            last_box=(131.5, 84.25, 41.0, 30.5),
        ),
        "last_boxes": LastBoxes(
            instance_id="host-a.1",
            worker=0,
            boxes=[LastBox(session_id="s1", frame_seq=41, box=(131.5, 84.25, 41.0, 30.5))],
        ),
    }


def wire(message: Message) -> dict[str, Any]:
    """The raw msgpack map of an encoded message."""
    return msgpack.unpackb(encode(message), raw=False)


def packed(fields: dict[str, Any], msg_type: str = "start", v: Any = SCHEMA_VERSION) -> bytes:
    return msgpack.packb({"v": v, "type": msg_type, **fields}, use_bin_type=True)


START = {
    "request_id": "r1",
    "stream_id": "cam1",
    "box": [10, 20, 30, 40],
    "preset": "arcf-hc",
}
FRAME = {"stream_id": "cam1", "seq": 0, "capture_ts_ns": 0, "encoding": "jpeg", "payload": b"\xff"}


def assert_error(
    data: bytes, cls: type[SchemaError], code: ErrorCode, **kwargs: Any
) -> SchemaError:
    with pytest.raises(cls) as info:
        decode(data, **kwargs)
    assert info.value.code is code
    assert isinstance(info.value, ValueError)
    assert str(info.value)
    return info.value


# --------------------------------------------------------------------------------------------
# Round trips
# --------------------------------------------------------------------------------------------


def test_samples_cover_every_message_type() -> None:
    assert set(samples()) == set(MESSAGE_TYPES)
    assert [m.type for m in MESSAGE_TYPES.values()] == list(MESSAGE_TYPES)


@pytest.mark.parametrize("msg_type", list(MESSAGE_TYPES))
def test_round_trip_every_message_type(msg_type: str) -> None:
    message = samples()[msg_type]
    data = encode(message)
    assert decode(data) == message
    assert decode(data, type(message)) == message
    raw = msgpack.unpackb(data, raw=False)
    assert list(raw)[:2] == ["v", "type"]
    assert raw["v"] == SCHEMA_VERSION and raw["type"] == msg_type
    assert None not in raw.values()  # optional fields are omitted, not sent as nil


def test_encoding_matches_plain_msgpack_and_uses_bin() -> None:
    for message in samples().values():
        raw = msgpack.unpackb(encode(message), raw=False)
        assert encode(message) == msgpack.packb(raw, use_bin_type=True)
    raw = wire(samples()["frame"])
    assert isinstance(raw["payload"], bytes)
    assert raw["encoding"] == "jpeg"  # enums travel as their string values
    assert wire(samples()["error"])["code"] == "no_session"
    assert wire(samples()["status"])["sessions"][0] == {
        "session_id": "s1",
        "stream_id": "cam1",
        "preset": "arcf-hc",
        "frames": 9,
    }


@pytest.mark.parametrize("size", [4095, 4096, 70_000, 100_000, 5 * 1024 * 1024])
def test_large_payload_round_trip_is_plain_msgpack(size: int) -> None:
    payload = os.urandom(size)
    frame = Frame(stream_id="cam1", seq=1, capture_ts_ns=2, encoding="png", payload=payload)
    data = encode(frame)
    # the hand-framed fast path gives exactly what msgpack itself would
    assert data == msgpack.packb(
        {
            "v": 1,
            "type": "frame",
            "stream_id": "cam1",
            "seq": 1,
            "capture_ts_ns": 2,
            "encoding": "png",
            "payload": payload,
        },
        use_bin_type=True,
    )
    decoded = decode(data, Frame)
    assert decoded.payload == payload
    assert decoded.width is None and decoded.height is None


def test_raw_frames_round_trip() -> None:
    bgr = Frame(
        stream_id="c", seq=0, capture_ts_ns=0, encoding="bgr8", width=4, height=3, payload=bytes(36)
    )
    gray = Frame(
        stream_id="c",
        seq=0,
        capture_ts_ns=0,
        encoding="gray8",
        width=4,
        height=3,
        payload=bytes(12),
    )
    assert decode(encode(bgr)) == bgr and decode(encode(gray)) == gray
    assert Encoding.BGR8.channels == 3 and Encoding.GRAY8.channels == 1
    assert Encoding.JPEG.channels is None and not Encoding.PNG.is_raw


def test_result_floats_may_be_nan() -> None:
    result = samples()["result"].model_copy(
        update={
            "box": (NAN, NAN, NAN, NAN),
            "peak": NAN,
            "psr": NAN,
            "aberrance": NAN,
            "aberrance_release": math.inf,
            "scale": NAN,
            "status": ResultStatus.ERROR,
            "message": "tracker failed",
        }
    )
    # model_copy does not validate: make sure validation itself accepts NaN too
    result = Result.model_validate(result.model_dump())
    back = decode(encode(result), Result)
    assert all(math.isnan(x) for x in back.box)
    assert math.isnan(back.peak) and math.isnan(back.psr) and math.isnan(back.scale)
    assert back.aberrance_release == math.inf
    assert back.status is ResultStatus.ERROR and back.message == "tracker failed"


def test_json_form_is_the_wire_map_and_validates_against_the_exported_schema() -> None:
    """``to_json``: a recording's results as a JSON reader takes them (no NaN token) and as
    the JSON Schema of their type validates them (``v`` and ``type``, no ``None``)."""
    import json

    jsonschema = pytest.importorskip("jsonschema")
    from arcf.schemas import to_json
    from arcf.schemas.export import message_schema

    tracked = samples()["result"]
    lost = tracked.model_copy(update={"box": (NAN, NAN, NAN, NAN), "peak": NAN,
                                      "aberrance_release": math.inf})
    for result in (tracked, lost):
        text = to_json(result).decode()
        assert "NaN" not in text and "Infinity" not in text
        body = json.loads(text)
        assert list(body)[:2] == ["v", "type"] and body["v"] == SCHEMA_VERSION
        # the wire's map (no None field), the non-finite numbers as null
        nulls = {"box": [None] * 4, "peak": None, "aberrance_release": None}
        assert body == {**msgpack.unpackb(encode(result)), **(nulls if result is lost else {})}
    jsonschema.validate(json.loads(to_json(tracked)), message_schema(Result))
    with pytest.raises(TypeError):
        to_json(object())  # type: ignore[arg-type]


def test_start_defaults_and_normalisation() -> None:
    start = decode(packed(START), StartRequest)
    assert start.box == (10.0, 20.0, 30.0, 40.0) and all(type(x) is float for x in start.box)
    assert start.overrides == {} and start.session_id is None and start.frame_seq is None
    explicit_nil = decode(packed({**START, "session_id": None, "frame_seq": None}))
    assert explicit_nil == start


def test_models_are_frozen_closed_and_typed() -> None:
    start = samples()["start"]
    with pytest.raises(ValidationError):
        start.preset = "bacf"  # type: ignore[misc]
    with pytest.raises(ValidationError, match="Extra inputs"):
        StopRequest(request_id="r", session_id="s", reason="x")  # type: ignore[call-arg]
    assert Frame.type == "frame" and StatusRequest.type == "status_request"
    # strict scalars: no silent coercion of strings, floats or bools
    for bad in ("5", 5.0, True):
        with pytest.raises(ValidationError):
            Frame(stream_id="c", seq=bad, capture_ts_ns=0, encoding="jpeg", payload=b"x")
    with pytest.raises(ValidationError):
        Frame(stream_id="c", seq=0, capture_ts_ns=0, encoding="jpeg", payload="text")


def test_encode_is_thread_safe() -> None:
    messages = [
        Frame(
            stream_id=f"cam{i}", seq=i, capture_ts_ns=i, encoding="jpeg", payload=os.urandom(9000)
        )
        for i in range(8)
    ]
    expected = [encode(m) for m in messages]
    failures: list[int] = []

    def work(i: int) -> None:
        for _ in range(200):
            if encode(messages[i]) != expected[i]:
                failures.append(i)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not failures


# --------------------------------------------------------------------------------------------
# Decoding errors
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\xc1",  # never-used msgpack byte
        b"not msgpack at all",
        msgpack.packb([1, 2, 3]),
        msgpack.packb("start"),
        msgpack.packb({1: "int keys"}),
        packed(START) + b"\x00",  # trailing garbage
        packed(START)[:-3],  # truncated
        msgpack.packb({"v": 1, "type": "start", "x": msgpack.ExtType(1, b"ext")}),
    ],
    ids=["empty", "c1", "text", "list", "str", "int-keys", "trailing", "truncated", "ext"],
)
def test_malformed_messages(data: bytes) -> None:
    assert_error(data, MalformedMessage, ErrorCode.MALFORMED_MESSAGE)


def test_envelope_errors() -> None:
    no_v = msgpack.packb({"type": "start", **START})
    err = assert_error(no_v, MalformedMessage, ErrorCode.MALFORMED_MESSAGE)
    assert "'v'" in str(err) and err.request_id == "r1"
    no_type = msgpack.packb({"v": 1, **START})
    assert "'type'" in str(assert_error(no_type, MalformedMessage, ErrorCode.MALFORMED_MESSAGE))
    assert_error(packed(START, v="1"), MalformedMessage, ErrorCode.MALFORMED_MESSAGE)
    assert_error(packed(START, v=True), MalformedMessage, ErrorCode.MALFORMED_MESSAGE)
    assert_error(packed(START, msg_type=3), MalformedMessage, ErrorCode.MALFORMED_MESSAGE)  # type: ignore[arg-type]
    err = assert_error(packed(START, v=2), UnsupportedVersion, ErrorCode.UNSUPPORTED_VERSION)
    assert "2" in str(err)
    err = assert_error(packed(START, msg_type="teleport"), UnknownType, ErrorCode.UNKNOWN_TYPE)
    assert "teleport" in str(err) and err.request_id == "r1"
    # version is checked before type: a v2 message may well have kinds v1 does not know
    assert_error(
        packed({}, msg_type="teleport", v=2), UnsupportedVersion, ErrorCode.UNSUPPORTED_VERSION
    )


def test_extra_field_is_invalid_request() -> None:
    err = assert_error(packed({**START, "frameseq": 4}), InvalidMessage, ErrorCode.INVALID_REQUEST)
    assert "frameseq" in str(err)
    # envelope keys are not fields: a message may not carry them twice or nest them
    assert_error(
        packed({**FRAME, "version": 1}, "frame"), InvalidMessage, ErrorCode.INVALID_REQUEST
    )


def test_what_the_service_sends_may_gain_fields_that_older_stations_ignore() -> None:
    """v1's compatibility rule: a newer service adds optional fields to what it sends; a
    station decodes the rest. Requests stay closed (a misspelt field is an error)."""
    for kind in ("result", "ack", "error", "status", "presets"):
        raw = {**wire(samples()[kind]), "added_in_a_later_release": [1, "x"]}
        assert decode(msgpack.packb(raw)) == samples()[kind]
    raw = wire(samples()["status"])
    raw["sessions"][0]["added_later"] = 1  # nested models of a reply too
    assert decode(msgpack.packb(raw)) == samples()["status"]
    for kind in ("frame", "start", "reinit", "stop", "status_request", "presets_request",
                 "session_spec", "last_boxes"):
        raw = {**wire(samples()[kind]), "added_in_a_later_release": 1}
        with pytest.raises(InvalidMessage):
            decode(msgpack.packb(raw))


def test_result_track_state_fields() -> None:
    result = samples()["result"].model_copy(
        update={"confidence": 0.83, "track_state": TrackState.COASTING, "reacquired": True})
    back = decode(encode(result), Result)
    assert (back.confidence, back.track_state, back.reacquired) == (
        0.83, TrackState.COASTING, True)
    # absent on a service that predates them, and on results without a box
    assert "confidence" not in wire(samples()["result"])
    assert decode(encode(samples()["result"]), Result).track_state is None
    for bad in ({"track_state": "searching"}, {"reacquired": 1}, {"confidence": "0.5"}):
        with pytest.raises(InvalidMessage):
            decode(msgpack.packb({**wire(samples()["result"]), **bad}))
    # the wire's states are the library's
    from arcf.state import TrackState as LibraryState

    assert [s.value for s in TrackState] == [s.value for s in LibraryState]


@pytest.mark.parametrize("field", ["request_id", "stream_id", "session_id", "preset"])
@pytest.mark.parametrize("bad", ["a/b", "*", "**", "$x", "a?b", "#", "", "x" * 65, "é", 7])
def test_bad_ids_are_invalid_requests(field: str, bad: Any) -> None:
    err = assert_error(packed({**START, field: bad}), InvalidMessage, ErrorCode.INVALID_REQUEST)
    assert field in str(err)
    assert isinstance(err, InvalidMessage) and err.errors[0]["loc"][0] == field


@pytest.mark.parametrize(
    ("box", "why"),
    [
        ([NAN, 0, 10, 10], "finite"),
        ([0, 0, math.inf, 10], "finite"),
        ([0, 0, -5, 10], "> 0"),
        ([0, 0, 10, 0], "> 0"),
        ([0, 0, 0, 0], "> 0"),
        ([0, 0, 1e12, 10], "within"),
        ([-1e9, 0, 10, 10], "within"),
        ([0, 0, 10], "4 numbers"),
        ([0, 0, 10, 10, 1], "4 numbers"),
        ("0 0 10 10", "4 numbers"),
        ([0, 0, "10", 10], "number"),
        ([0, 0, True, 10], "number"),
        (None, "4 numbers"),
    ],
)
@pytest.mark.parametrize("msg_type", ["start", "reinit"])
def test_bad_boxes_are_invalid_box(box: Any, why: str, msg_type: str) -> None:
    fields = START if msg_type == "start" else {"request_id": "r", "session_id": "s"}
    err = assert_error(
        packed({**fields, "box": box}, msg_type), InvalidMessage, ErrorCode.INVALID_BOX
    )
    assert "box" in str(err) and why in str(err)
    # constructing the model directly fails the same way
    with pytest.raises(ValidationError, match="box"):
        MESSAGE_TYPES[msg_type].model_validate({**fields, "box": box})


def test_box_and_another_field_failing_is_invalid_request() -> None:
    err = assert_error(
        packed({**START, "box": [0, 0, 0, 0], "stream_id": "*"}),
        InvalidMessage,
        ErrorCode.INVALID_REQUEST,
    )
    assert "box" in str(err) and "stream_id" in str(err)


def test_result_box_must_still_have_four_items() -> None:
    raw = wire(samples()["result"])
    raw["box"] = [1.0, 2.0]
    assert_error(msgpack.packb(raw), InvalidMessage, ErrorCode.INVALID_BOX)


@pytest.mark.parametrize(
    ("fields", "fragment"),
    [
        ({**FRAME, "seq": -1}, "seq"),
        ({**FRAME, "capture_ts_ns": -5}, "capture_ts_ns"),
        ({**FRAME, "seq": 2**64 - 1}, "seq"),  # beyond int64
        ({**FRAME, "seq": 1.0}, "seq"),
        ({**FRAME, "encoding": "webp"}, "encoding"),
        ({**FRAME, "payload": "text, not bin"}, "payload"),
        ({**FRAME, "payload": b""}, "payload"),
        ({**FRAME, "width": 0}, "width"),
        ({**FRAME, "encoding": "bgr8", "width": 4, "height": 3, "payload": bytes(35)}, "36"),
        ({**FRAME, "encoding": "gray8", "width": 4, "height": 3, "payload": bytes(36)}, "12"),
        ({**FRAME, "encoding": "gray8", "payload": bytes(12)}, "width and height"),
    ],
)
def test_bad_frames_are_invalid_requests(fields: dict[str, Any], fragment: str) -> None:
    err = assert_error(packed(fields, "frame"), InvalidMessage, ErrorCode.INVALID_REQUEST)
    assert fragment in str(err)


def test_negative_frame_seq_in_requests() -> None:
    assert_error(packed({**START, "frame_seq": -1}), InvalidMessage, ErrorCode.INVALID_REQUEST)


def test_overrides_limits() -> None:
    """A bad override is ``invalid_parameter`` whether the schema or the presets refuse it;
    the field is named."""
    many = {f"p{i}": i for i in range(33)}
    err = assert_error(
        packed({**START, "overrides": many}), InvalidMessage, ErrorCode.INVALID_PARAMETER
    )
    assert "overrides" in str(err)
    ok = {f"p{i}": i for i in range(32)}
    assert decode(packed({**START, "overrides": ok}), StartRequest).overrides == ok
    for bad in ([1, 2], {"a": 1}, None, NAN, "x" * 257, b"bytes"):
        err = assert_error(
            packed({**START, "overrides": {"gamma": bad}}),
            InvalidMessage,
            ErrorCode.INVALID_PARAMETER,
        )
        assert "overrides.gamma" in str(err)
    for bad_key in ("", "a b", "1abc", "a/b", "x" * 65):
        assert_error(packed({**START, "overrides": {bad_key: 1}}), InvalidMessage,
                     ErrorCode.INVALID_PARAMETER)
    mixed = {**START, "overrides": {"gamma": NAN}, "box": [1, 2, 3]}  # two kinds of field
    assert_error(packed(mixed), InvalidMessage, ErrorCode.INVALID_REQUEST)
    kinds = decode(packed({**START, "overrides": {"b": True, "i": 1, "f": 1.5, "s": "x"}}))
    assert [type(v) for v in kinds.overrides.values()] == [bool, int, float, str]  # type: ignore[attr-defined]


def test_oversized_payload() -> None:
    data = encode(
        Frame(stream_id="c", seq=3, capture_ts_ns=0, encoding="jpeg", payload=bytes(2000))
    )
    assert decode(data, max_payload=2000).payload == bytes(2000)  # type: ignore[attr-defined]
    err = assert_error(data, OversizedPayload, ErrorCode.OVERSIZED_PAYLOAD, max_payload=1999)
    assert "1999" in str(err)
    # a message far larger than any allowed payload is refused before it is parsed
    huge = b"\x00" * (1024 * 1024 + 10)
    assert_error(huge, OversizedPayload, ErrorCode.OVERSIZED_PAYLOAD, max_payload=1)


def test_abusive_containers_are_refused() -> None:
    assert_error(
        packed({**START, "x": list(range(20_000))}), MalformedMessage, ErrorCode.MALFORMED_MESSAGE
    )
    assert_error(
        packed({**START, "x": "y" * 70_000}), MalformedMessage, ErrorCode.MALFORMED_MESSAGE
    )
    # 5000 nested one-item arrays: msgpack's depth guard, not a Python RecursionError
    head = msgpack.packb({"v": 1, "type": "start"})
    nested = bytes([head[0] + 1]) + head[1:] + msgpack.packb("x") + b"\x91" * 5000 + b"\x01"
    assert_error(nested, MalformedMessage, ErrorCode.MALFORMED_MESSAGE)


def test_error_messages_stay_short_whatever_was_sent() -> None:
    junk = {f"{i:04d}" + "k" * 1000: i for i in range(200)}
    err = assert_error(packed({**START, **junk}), InvalidMessage, ErrorCode.INVALID_REQUEST)
    assert len(str(err)) < 1500 and "and 192 more" in str(err)
    assert isinstance(err, InvalidMessage) and len(err.errors) == 200


def test_expected_type() -> None:
    data = encode(samples()["frame"])
    assert isinstance(decode(data, Frame), Frame)
    assert isinstance(decode(data, (StartRequest, Frame)), Frame)
    err = assert_error(
        data, UnexpectedType, ErrorCode.INVALID_REQUEST, expected=(StartRequest, StopRequest)
    )
    assert "'frame'" in str(err) and "'start'" in str(err) and err.stream_id == "cam1"
    assert err.frame_seq == 7
    # the type is checked before the fields: a bad frame sent to control is "unexpected"
    assert_error(
        packed({"seq": -1}, "frame"),
        UnexpectedType,
        ErrorCode.INVALID_REQUEST,
        expected=StartRequest,
    )


def test_errors_carry_ids_for_the_reply() -> None:
    err = assert_error(
        packed({**START, "box": [0, 0, -1, 1], "session_id": "s9"}),
        InvalidMessage,
        ErrorCode.INVALID_BOX,
    )
    reply = err.to_error_message()
    assert reply.code is ErrorCode.INVALID_BOX
    assert (reply.request_id, reply.stream_id, reply.session_id) == ("r1", "cam1", "s9")
    assert decode(encode(reply), ErrorMessage) == reply
    # ids that are themselves invalid are not echoed
    err = assert_error(
        packed({**START, "request_id": "a/b"}), InvalidMessage, ErrorCode.INVALID_REQUEST
    )
    assert err.request_id is None and err.to_error_message().request_id is None


def test_decode_accepts_buffers_and_rejects_non_bytes() -> None:
    data = encode(samples()["stop"])
    assert decode(bytearray(data)) == decode(memoryview(data)) == samples()["stop"]
    with pytest.raises(TypeError):
        decode("text")  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        encode({"v": 1})  # type: ignore[arg-type]


def test_error_codes_match_the_design() -> None:
    """The contract's table lists every code, once, and nothing else."""
    design = (Path(__file__).parents[2] / "docs" / "wire-contract.md").read_text()
    table = design.split("## Error codes", 1)[1]
    rows = re.findall(r"^\| `([a-z_]+)` \|", table, flags=re.M)
    assert sorted(rows) == sorted(code.value for code in ErrorCode)
    assert len(rows) == len(set(rows))


# --------------------------------------------------------------------------------------------
# Key expressions
# --------------------------------------------------------------------------------------------


def test_key_builders() -> None:
    keys = KeySpace()
    assert keys.prefix == "arcf/v1"
    assert keys.frames("cam1") == "arcf/v1/streams/cam1/frames"
    assert keys.all_frames() == "arcf/v1/streams/*/frames"
    assert keys.results("cam1", "s1") == "arcf/v1/streams/cam1/sessions/s1/results"
    assert keys.results_of_stream("cam1") == "arcf/v1/streams/cam1/sessions/*/results"
    assert keys.all_results() == "arcf/v1/streams/*/sessions/*/results"
    assert keys.errors("cam1") == "arcf/v1/streams/cam1/errors"
    assert keys.all_errors() == "arcf/v1/streams/*/errors"
    assert keys.control() == "arcf/v1/control"
    assert keys.worker_token("host-a", "w0") == "arcf/v1/workers/host-a/w0"
    assert keys.workers_of_instance("host-a") == "arcf/v1/workers/host-a/*"
    assert keys.all_workers() == "arcf/v1/workers/*/*"
    custom = KeySpace("fleet/site-3/arcf")
    assert custom.control() == "fleet/site-3/arcf/control"


@pytest.mark.parametrize("bad", ["a/b", "*", "**", "$*", "a?b", "#", "", "@x", "x" * 65, None])
def test_key_builders_reject_bad_ids(bad: Any) -> None:
    keys = KeySpace()
    with pytest.raises(InvalidKey):
        keys.frames(bad)
    with pytest.raises(InvalidKey):
        keys.results("cam1", bad)
    with pytest.raises(InvalidKey):
        keys.worker_token(bad, "w0")


@pytest.mark.parametrize(
    "prefix", ["", "/arcf", "arcf/", "arcf//v1", "arcf/*", "arcf/**", "arcf/$*", "a?b", "@/arcf", 3]
)
def test_bad_prefixes(prefix: Any) -> None:
    with pytest.raises(InvalidKey):
        KeySpace(prefix)


def test_key_parsers() -> None:
    keys = KeySpace()
    assert keys.stream_of_frames_key("arcf/v1/streams/cam-1.a_b/frames") == "cam-1.a_b"
    assert keys.stream_of_errors_key(keys.errors("cam1")) == "cam1"
    assert keys.parse_results_key(keys.results("cam1", "s1")) == ("cam1", "s1")
    assert keys.parse_worker_key(keys.worker_token("i1", "w3")) == ("i1", "w3")
    assert keys.is_control_key("arcf/v1/control") and not keys.is_control_key("arcf/v1/controls")
    for bad in [
        "arcf/v2/streams/cam1/frames",  # other prefix
        "arcf/v1/streams/cam1/errors",  # other key kind
        "arcf/v1/streams/cam1/x/frames",  # extra chunk
        "arcf/v1/streams/*/frames",  # wildcard, not a sample key
        "arcf/v1/streams//frames",
        "arcf/v1/streams/cam1/frames/",
        "arcf/v1x/streams/cam1/frames",
    ]:
        with pytest.raises(InvalidKey):
            keys.stream_of_frames_key(bad)
    with pytest.raises(InvalidKey):
        keys.parse_results_key("arcf/v1/streams/cam1/sessions/*/results")
    with pytest.raises(InvalidKey):
        keys.parse_worker_key("arcf/v1/workers/i1")


def test_keys_are_canonical_zenoh_key_expressions_with_the_intended_matching() -> None:
    zenoh = pytest.importorskip("zenoh")
    key_expr = zenoh.KeyExpr
    keys = KeySpace()

    def hits(pattern: str, key: str) -> bool:
        return bool(key_expr(pattern).intersects(key_expr(key)))

    built = [
        keys.frames("cam1"),
        keys.all_frames(),
        keys.results("cam1", "s1"),
        keys.results_of_stream("cam1"),
        keys.all_results(),
        keys.errors("cam1"),
        keys.all_errors(),
        keys.control(),
        keys.worker_token("i1", "w0"),
        keys.workers_of_instance("i1"),
        keys.all_workers(),
        keys.frames("..."),  # odd but valid ids are still single literal chunks
    ]
    for key in built:
        assert str(key_expr(key)) == key  # valid and already canonical

    assert hits(keys.all_frames(), keys.frames("cam1"))
    assert hits(keys.all_frames(), keys.frames("-._"))
    assert not hits(keys.all_frames(), keys.errors("cam1"))
    assert not hits(keys.all_frames(), keys.results("cam1", "s1"))
    assert not hits(keys.all_frames(), "arcf/v1/streams/a/b/frames")  # * is one chunk
    assert not hits(keys.all_frames(), KeySpace("arcf/v2").frames("cam1"))
    assert hits(keys.results_of_stream("cam1"), keys.results("cam1", "s1"))
    assert not hits(keys.results_of_stream("cam1"), keys.results("cam2", "s1"))
    assert hits(keys.all_results(), keys.results("cam2", "s1"))
    assert not hits(keys.all_results(), keys.frames("cam1"))
    assert hits(keys.all_errors(), keys.errors("cam1"))
    assert hits(keys.all_workers(), keys.worker_token("i1", "w0"))
    assert hits(keys.workers_of_instance("i1"), keys.worker_token("i1", "w0"))
    assert not hits(keys.workers_of_instance("i1"), keys.worker_token("i2", "w0"))
    assert not hits(keys.control(), keys.frames("cam1"))
    assert not hits(keys.frames("cam1"), keys.frames("cam10"))


# --------------------------------------------------------------------------------------------
# JSON Schema export
# --------------------------------------------------------------------------------------------


def test_committed_json_schemas_are_current(tmp_path: Path) -> None:
    """A model change without `python -m arcf.schemas.export` fails here (and in CI)."""
    assert export.main(["--out", str(tmp_path)]) == 0
    committed = export.DEFAULT_OUT
    fresh = {p.name: p.read_bytes() for p in sorted(tmp_path.iterdir())}
    current = {p.name: p.read_bytes() for p in sorted(committed.glob("*.json"))}
    assert sorted(fresh) == sorted(current), "run `python -m arcf.schemas.export`"
    for name, text in fresh.items():
        assert current[name] == text, f"{name} is stale: run `python -m arcf.schemas.export`"
    assert export.check(committed) == []


def test_export_files_shape(tmp_path: Path) -> None:
    import json

    export.write(tmp_path)
    names = {p.name for p in tmp_path.iterdir()}
    assert names == {f"{t}.schema.json" for t in MESSAGE_TYPES} | {"index.json"}
    for msg_type, model in MESSAGE_TYPES.items():
        text = (tmp_path / f"{msg_type}.schema.json").read_text()
        assert text.endswith("}\n") and '\n  "' in text
        schema = json.loads(text)
        assert list(schema)[:4] == ["$schema", "$id", "title", "description"]
        assert schema["$id"].endswith(msg_type) and schema["title"] == model.__name__
        assert schema["properties"]["v"]["const"] == SCHEMA_VERSION
        assert schema["properties"]["type"]["const"] == msg_type
        assert schema["required"][:2] == ["v", "type"]
        assert list(schema["properties"])[:2] == ["v", "type"]
        # requests are closed; what the service sends is open for additions within v1
        assert schema["additionalProperties"] is (model.model_config["extra"] == "ignore")
    frame = json.loads((tmp_path / "frame.schema.json").read_text())
    payload = frame["properties"]["payload"]
    assert payload["x-msgpack"] == "bin" and "base64" in payload["description"]
    index = json.loads((tmp_path / "index.json").read_text())
    assert [m["type"] for m in index["messages"]] == list(MESSAGE_TYPES)
    assert index["error_codes"] == [c.value for c in ErrorCode]
    assert "<prefix>/streams/<stream>/sessions/<session>/results" in [
        k["key"] for k in index["key_expressions"]
    ]
    # stale files of removed models are reported, then deleted by the next export
    (tmp_path / "teleport.schema.json").write_text("{}\n")
    assert any("teleport" in problem for problem in export.check(tmp_path))
    assert export.main(["--out", str(tmp_path), "--check"]) == 1
    export.write(tmp_path)
    assert not (tmp_path / "teleport.schema.json").exists()
    assert export.main(["--out", str(tmp_path), "--check"]) == 0


#: JSON Schema 2020-12's keywords (core, applicator, validation, meta-data, format, content)
JSON_SCHEMA_KEYWORDS = {
    "$schema", "$id", "$ref", "$defs", "$comment", "$anchor", "$dynamicRef", "$dynamicAnchor",
    "$vocabulary", "allOf", "anyOf", "oneOf", "not", "if", "then", "else", "dependentSchemas",
    "prefixItems", "items", "contains", "properties", "patternProperties",
    "additionalProperties", "propertyNames", "unevaluatedItems", "unevaluatedProperties",
    "type", "enum", "const", "multipleOf", "maximum", "exclusiveMaximum", "minimum",
    "exclusiveMinimum", "maxLength", "minLength", "pattern", "maxItems", "minItems",
    "uniqueItems", "maxContains", "minContains", "maxProperties", "minProperties", "required",
    "dependentRequired", "title", "description", "default", "deprecated", "readOnly",
    "writeOnly", "examples", "format", "contentEncoding", "contentMediaType", "contentSchema",
}


def _unknown_keywords(node: object, path: str = "") -> list[str]:
    """Keys of a schema that no JSON Schema validator knows (``x-`` extensions allowed)."""
    found = []
    if isinstance(node, dict):
        for key, value in node.items():
            if key in ("properties", "$defs", "patternProperties") and isinstance(value, dict):
                for name, sub in value.items():
                    found += _unknown_keywords(sub, f"{path}/{key}/{name}")
                continue
            if key not in JSON_SCHEMA_KEYWORDS and not key.startswith("x-"):
                found.append(f"{path}/{key}")
            found += _unknown_keywords(value, f"{path}/{key}")
    elif isinstance(node, list):
        for k, item in enumerate(node):
            found += _unknown_keywords(item, f"{path}/{k}")
    return found


def test_exported_json_schemas_are_valid_json_schema() -> None:
    """Each file passes the 2020-12 metaschema and uses only its keywords: a validator in
    another language reads every constraint (pydantic's own ``ge`` once leaked into one)."""
    import jsonschema

    for name, schema in export.build_all().items():
        if name == "index.json":
            continue
        jsonschema.Draft202012Validator.check_schema(schema)
        assert _unknown_keywords(schema) == [], name
    assert _unknown_keywords({"type": "number", "ge": 0}) == ["/ge"]


def test_encoded_samples_validate_against_their_json_schema() -> None:
    import jsonschema

    # msgpack bin has no JSON counterpart: the schemas describe it as a binary "string"
    checker = jsonschema.Draft202012Validator.TYPE_CHECKER.redefine(
        "string", lambda _checker, value: isinstance(value, (str, bytes))
    )
    validator_cls = jsonschema.validators.extend(
        jsonschema.Draft202012Validator, type_checker=checker
    )
    schemas = export.build_all()
    nan_result = Result.model_validate({**samples()["result"].model_dump(), "peak": NAN})
    for message in [*samples().values(), nan_result]:
        raw = msgpack.unpackb(encode(message), raw=False)
        validator_cls(schemas[f"{message.type}.schema.json"]).validate(raw)
    bad = msgpack.unpackb(encode(samples()["start"]), raw=False)
    bad["box"] = [0, 0, -1, 5]
    with pytest.raises(jsonschema.ValidationError):
        validator_cls(schemas["start.schema.json"]).validate(bad)
    bad = {**msgpack.unpackb(encode(samples()["stop"]), raw=False), "extra": 1}
    with pytest.raises(jsonschema.ValidationError):
        validator_cls(schemas["stop.schema.json"]).validate(bad)
