"""The encoding table: every wire encoding has one entry, and each entry's operations agree
with each other and with the worker's checks (sizes, error codes) on real pictures."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from arcf.client.media.encodings import (
    ENCODINGS,
    VIDEO_ENCODINGS,
    codec_of,
    decode_image,
    encode_image,
    video_codec,
)
from arcf.schemas import Encoding, ErrorCode


def frame(payload: bytes, encoding: str, width: int | None = None,
          height: int | None = None) -> SimpleNamespace:
    return SimpleNamespace(payload=payload, encoding=encoding, width=width, height=height)


@pytest.fixture(scope="module")
def picture(wakeboard7) -> np.ndarray:  # type: ignore[no-untyped-def]
    image = cv2.imread(str(wakeboard7.frames[0]), cv2.IMREAD_COLOR)
    assert image is not None
    return image


def test_every_wire_encoding_has_one_entry() -> None:
    assert set(ENCODINGS) == set(Encoding)
    for encoding, codec in ENCODINGS.items():
        assert codec.encoding is encoding and codec_of(encoding.value) is codec
        assert codec.is_video == encoding.is_video and (codec.kind == "raw") == encoding.is_raw
        if codec.kind == "image":
            assert codec.read_size is not None and codec.decode is not None
        if codec.is_video:
            assert codec.decoder_name and codec.encoder_name and codec.keyframe_types
    assert set(VIDEO_ENCODINGS) == {"h264", "h265"}
    with pytest.raises(ValueError, match="unknown encoding 'webp'"):
        codec_of("webp")
    assert video_codec("h265") is ENCODINGS[Encoding.H265]
    assert video_codec("jpeg") is None and video_codec("vp9") is None


@pytest.mark.parametrize("encoding", ["jpeg", "png", "bgr8", "gray8"])
def test_encoded_pictures_decode_to_their_size(picture: np.ndarray, encoding: str) -> None:
    image = picture if encoding != "gray8" else cv2.cvtColor(picture, cv2.COLOR_BGR2GRAY)
    payload = encode_image(image, encoding, 90)
    h, w = image.shape[:2]
    codec = codec_of(encoding)
    if codec.read_size is not None:
        assert codec.read_size(payload) == (w, h)
    pixels, problem = decode_image(frame(payload, encoding, w, h), max_pixels=w * h)
    assert problem is None and isinstance(pixels, np.ndarray)
    assert pixels.shape == image.shape
    if encoding in ("png", "bgr8", "gray8"):  # lossless
        assert np.array_equal(pixels, image)
    else:
        assert np.abs(pixels.astype(int) - image).mean() < 4


@pytest.mark.parametrize("encoding", ["jpeg", "png", "bgr8"])
def test_the_size_limit_refuses_before_decoding(picture: np.ndarray, encoding: str) -> None:
    payload = encode_image(picture, encoding)
    h, w = picture.shape[:2]
    pixels, problem = decode_image(frame(payload, encoding, w, h), max_pixels=w * h - 1)
    assert pixels is None and problem is not None
    assert problem[0] is ErrorCode.IMAGE_TOO_LARGE and str(w * h - 1) in problem[1]


def test_errors_name_their_cause(picture: np.ndarray) -> None:
    jpeg = encode_image(picture, "jpeg")
    assert decode_image(frame(b"\xff\xd8junk", "jpeg"), 10**7)[1] == (
        ErrorCode.DECODE_ERROR, "not a readable jpeg header")
    code, text = decode_image(frame(jpeg[:600], "jpeg"), 10**7)[1] or ("", "")
    assert code is ErrorCode.DECODE_ERROR and text.startswith("cannot decode jpeg frame")
    code, text = decode_image(frame(b"\0" * 11, "gray8", 4, 3), 10**7)[1] or ("", "")
    assert code is ErrorCode.DECODE_ERROR and "11 bytes, expected 12" in text
    code, text = decode_image(frame(b"\0\0\0\1", "h264"), 10**7)[1] or ("", "")
    assert code is ErrorCode.DECODE_ERROR and "stream's decoder" in text
    with pytest.raises(ValueError, match="not encoded one picture at a time"):
        encode_image(picture, "h264")


def test_a_region_of_a_jpeg_is_the_whole_decode_there(picture: np.ndarray) -> None:
    from arcf.client.media.images import REGION_DECODING, decode_compressed

    if not REGION_DECODING:
        pytest.skip("the _jpegregion module was not built")
    jpeg = encode_image(picture, "jpeg")
    whole = decode_compressed(jpeg)
    part, problem = decode_image(frame(jpeg, "jpeg"), 10**7, region=(200, 300, 400, 600))
    assert problem is None and not isinstance(part, np.ndarray) and part is not None
    t, lf, b, r = part.region
    assert np.array_equal(part.pixels[t:b, lf:r], whole[t:b, lf:r])


@pytest.mark.parametrize("encoding", VIDEO_ENCODINGS)
def test_video_entries_find_keyframes_and_decode_the_stream(picture: np.ndarray,
                                                            encoding: str) -> None:
    from arcf.client.media.video import Outcome
    from arcf.loadtools.video import encode_video

    small = cv2.resize(picture, (320, 180))
    units = encode_video([small] * 6, encoding, gop=3)
    codec = codec_of(encoding)
    assert [codec.is_keyframe(u) for u in units] == [True, False, False, True, False, False]
    decoder = codec.stream_decoder(320 * 180)
    outcomes = [decoder.decode(i, u).outcome for i, u in enumerate(units)]
    assert outcomes.count(Outcome.FRAME) == 6
    size = codec.size_reader(320 * 180)
    for u in units:
        size.feed(u)
    assert size.read() == (320, 180)
