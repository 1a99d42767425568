"""Image sizes read from headers, and decompression bombs refused before decoding."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import simplejpeg

from arcf.client.media.encodings import decode_image
from arcf.client.media.headers import image_size


def frame(payload: bytes, encoding: str) -> SimpleNamespace:
    return SimpleNamespace(payload=payload, encoding=encoding, width=None, height=None)


@pytest.mark.parametrize("params", [[], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]])
def test_jpeg_sizes_baseline_and_progressive(params: list[int]) -> None:
    image = np.random.default_rng(0).integers(0, 255, (37, 53, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(".jpg", image, params)
    assert ok and image_size(buf.tobytes()) == (53, 37)


def test_png_size_and_a_real_dataset_frame(tmp_path) -> None:
    ok, buf = cv2.imencode(".png", np.zeros((21, 34), np.uint8))
    assert ok and image_size(buf.tobytes()) == (34, 21)
    from arcf.data import data_root

    frames = sorted((data_root() / "uav123_10fps").rglob("*.jpg"))[:1]
    if frames:
        assert image_size(frames[0].read_bytes()) == (1280, 720)


@pytest.mark.parametrize("junk", [b"", b"\xff\xd8", b"\xff\xd8\xff\xe0\x00", b"GIF89a....",
                                  b"\x89PNG\r\n\x1a\n\x00\x00", b"\xff\xd8\x00\x00\x00\x00"])
def test_unreadable_headers_give_none(junk: bytes) -> None:
    assert image_size(junk) is None


def test_a_decompression_bomb_is_refused_without_decoding(png_bomb, monkeypatch) -> None:
    bomb = png_bomb(10000, 10000)  # 100 MB of pixels in a ~100 KB file
    assert len(bomb) < 200_000 and image_size(bomb) == (10000, 10000)
    decoded: list[int] = []

    def imdecode(*args: object, **kwargs: object) -> None:
        decoded.append(1)
        raise AssertionError("the bomb reached a decoder")

    # both decoders a frame can reach (simplejpeg for JPEG, OpenCV for the rest)
    monkeypatch.setattr(cv2, "imdecode", imdecode)
    monkeypatch.setattr(simplejpeg, "decode_jpeg", imdecode)
    image, problem = decode_image(frame(bomb, "png"), max_pixels=40_000_000)
    assert image is None and problem is not None and problem[0] == "image_too_large"
    assert "10000x10000" in problem[1]
    assert decoded == []  # refused from the header, not decoded


def test_images_within_the_limit_decode() -> None:
    _, buf = cv2.imencode(".jpg", np.full((40, 60, 3), 128, np.uint8))
    image, problem = decode_image(frame(buf.tobytes(), "jpeg"), max_pixels=2400)
    assert problem is None and image is not None and image.shape == (40, 60, 3)
    image, problem = decode_image(frame(buf.tobytes(), "jpeg"), max_pixels=2399)
    assert image is None and problem is not None and problem[0] == "image_too_large"
    raw = SimpleNamespace(payload=bytes(6000 * 3), encoding="bgr8", width=100, height=60)
    assert decode_image(raw, max_pixels=5999)[1][0] == "image_too_large"


def test_jpeg_frames_decode_to_opencvs_pixels() -> None:
    """The fast JPEG path (simplejpeg) gives exactly cv2.imdecode's pixels: colour with 4:2:0
    and 4:4:4 chroma, progressive, grey, real benchmark frames; a truncated stream is left to
    OpenCV, which handles it as before."""
    from pathlib import Path

    from arcf.data import data_root

    rng = np.random.default_rng(5)
    colour = cv2.GaussianBlur(rng.integers(0, 256, (90, 130, 3), dtype=np.uint8), (0, 0), 2)
    payloads = [
        cv2.imencode(".jpg", colour, params)[1].tobytes()
        for params in ([cv2.IMWRITE_JPEG_QUALITY, 95],
                       [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444],
                       [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    ]
    payloads.append(cv2.imencode(".jpg", cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))[1].tobytes())
    payloads += [p.read_bytes() for p in sorted(Path(data_root()).glob("*/*/*/*.jpg"))[:3]]
    payloads.append(payloads[0][: len(payloads[0]) * 2 // 3])  # truncated
    for payload in payloads:
        expected = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_UNCHANGED)
        image, problem = decode_image(frame(payload, "jpeg"), max_pixels=10**8)
        if expected is None:  # OpenCV 5 refuses the truncated stream: so does decode_image
            assert image is None and problem is not None and problem[0] == "decode_error"
            continue
        assert problem is None
        assert image is not None and image.shape == expected.shape
        np.testing.assert_array_equal(image, expected)
