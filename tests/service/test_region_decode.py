"""Pictures decoded or converted only where the trackers read: the same pixels as the whole
picture's there, bit for bit, and the whole picture wherever that cannot be promised.

JPEG: the shared sequences' own files (4:2:0) and re-encodings of them in the layouts cameras
send (4:4:4, 4:2:2, grey, restart markers, odd sizes), cut at random rectangles. H.264: a
real libx264 stream of a shared sequence, converted by regions against the whole picture's
conversion.
"""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pytest
import simplejpeg

from arcf.client.media import images as decoding
from arcf.client.media.convert import converts_by_region, picture_bgr, picture_bgr_region
from arcf.client.media.encodings import encode_image
from arcf.client.media.images import decode_compressed, decode_jpeg_region
from arcf.eval.datasets import load_dataset
from arcf.loadtools.video import encode_video
from arcf.region import RegionFrame, contains

pytestmark = pytest.mark.skipif(not decoding.REGION_DECODING,
                                reason="the _jpegregion module was not built")

SEQUENCES = [("uav123_10fps", "wakeboard7"), ("uav123_10fps", "truck4_1"), ("dtb70", "Animal3")]


def _frames(dataset: str, name: str) -> list[Path]:
    try:
        (seq,) = load_dataset(dataset, sequences=[name])
    except (FileNotFoundError, KeyError):
        pytest.skip("needs ../shared/data")
    return list(seq.frames)


def _files() -> list[bytes]:
    return [p.read_bytes() for ds, name in SEQUENCES for p in _frames(ds, name)[::25]]


#: Restart intervals that tile a 1280-wide picture's MCU grid, where a decode reads only the
#: intervals covering the region: 4:2:0 a row or 8 MCUs (as the SDK writes it) or 1 MCU;
#: 4:4:4 10 MCUs; 4:2:2 two rows
RESTART = (
    [cv2.IMWRITE_JPEG_RST_INTERVAL, 80],
    [cv2.IMWRITE_JPEG_RST_INTERVAL, 8],
    [cv2.IMWRITE_JPEG_RST_INTERVAL, 1],
    [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444,
     cv2.IMWRITE_JPEG_RST_INTERVAL, 10],
    [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422,
     cv2.IMWRITE_JPEG_RST_INTERVAL, 160],
)


@pytest.fixture(scope="module")
def jpegs() -> list[bytes]:
    files = _files()
    image = decode_compressed(files[0])
    encoded = []
    for params in ([cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444],
                   [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422],
                   [cv2.IMWRITE_JPEG_RST_INTERVAL, 3], [cv2.IMWRITE_JPEG_QUALITY, 40],
                   *RESTART):
        encoded.append(cv2.imencode(".jpg", image, params)[1].tobytes())
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    encoded.append(cv2.imencode(".jpg", grey)[1].tobytes())
    encoded.append(cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_RST_INTERVAL, 20])[1].tobytes())
    encoded.append(encode_image(image[:357, :611], "jpeg"))  # the SDK's, 13-MCU intervals
    encoded.append(cv2.imencode(".jpg", image[:357, :611])[1].tobytes())  # not whole MCUs
    return files + encoded


def _random_regions(rng: np.random.Generator, h: int, w: int, n: int):  # type: ignore[no-untyped-def]
    for _ in range(n):
        rh = int(rng.integers(1, h // 2))
        rw = int(rng.integers(1, max(2, min(w, h * w // 2 // rh))))
        t, lf = int(rng.integers(0, h - rh + 1)), int(rng.integers(0, w - rw + 1))
        yield t, lf, t + rh, lf + rw
    yield 0, 0, h // 3, w  # the top edge, the whole width
    yield h - 40, w - 40, h, w  # a corner


def test_a_jpeg_region_has_the_whole_decodes_pixels(jpegs: list[bytes]) -> None:
    rng = np.random.default_rng(3)
    checked = 0
    for data in jpegs:
        whole = decode_compressed(data)
        h, w = whole.shape[:2]
        for region in _random_regions(rng, h, w, 6):
            got = decode_jpeg_region(data, region)
            assert isinstance(got, RegionFrame), region
            assert contains(got.region, region)
            assert got.pixels.shape == whole.shape
            t, lf, b, r = got.region
            np.testing.assert_array_equal(got.pixels[t:b, lf:r], whole[t:b, lf:r])
            np.testing.assert_array_equal(got.whole(), whole)
            checked += 1
    assert checked >= 8 * len(jpegs)


def test_a_region_is_read_from_the_restart_intervals_that_cover_it(jpegs: list[bytes]) -> None:
    """Restart intervals that tile the MCU grid: only the intervals covering the region are
    read (pixels checked by the test above, bit for bit), from the first of them; intervals
    that do not tile it, no markers, or a region that starts at the top-left over the whole
    width: read from the picture's top."""
    from arcf.client.media import _jpegregion

    image = decode_compressed(jpegs[0])
    assert image.shape[:2] == (720, 1280)
    region = (300, 300, 340, 400)
    starts = [_jpegregion.seek(cv2.imencode(".jpg", image, params)[1].tobytes(), *region)
              for params in RESTART]
    # 4:2:0 (16-pixel MCUs): a row; 8 MCUs (128 px); 1 MCU; 4:4:4 (8 px): 10 MCUs;
    # 4:2:2 (16 x 8): two rows
    assert starts == [(288, 0), (288, 256), (288, 288), (296, 240), (288, 0)]
    sent = encode_image(image, "jpeg")  # the SDK's: 8-MCU intervals
    assert _jpegregion.seek(sent, *region) == (288, 256)
    assert _jpegregion.seek(sent, 0, 0, 100, 1280) is None  # nothing to leave out
    assert _jpegregion.seek(sent, 0, 200, 100, 400) == (0, 128)
    block = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_RST_INTERVAL, 3])[1].tobytes()
    assert _jpegregion.seek(block, *region) is None  # 3 MCUs do not tile a row of 80
    assert _jpegregion.seek(jpegs[0], *region) is None  # no restart markers


def test_a_damaged_restart_marker_is_not_where_a_region_starts(jpegs: list[bytes]) -> None:
    """A restart marker out of sequence before the region: no seek, and the decode that reads
    from the top finds the damage (the whole decode decides, as for any damage)."""
    from arcf.client.media import _jpegregion

    data = bytearray(encode_image(decode_compressed(jpegs[0]), "jpeg"))
    markers = [i for i in range(len(data) - 1)
               if data[i] == 0xFF and 0xD0 <= data[i + 1] <= 0xD7]
    assert len(markers) == 45 * 10 - 1  # 45 MCU rows of 10 intervals
    assert [data[i + 1] - 0xD0 for i in markers[:10]] == [0, 1, 2, 3, 4, 5, 6, 7, 0, 1]
    data[markers[5] + 1] = 0xD0  # RST5 -> RST0
    assert _jpegregion.seek(bytes(data), 600, 100, 700, 400) is None
    assert decode_jpeg_region(bytes(data), (600, 100, 700, 400)) is None


def test_what_a_region_cannot_promise_is_decoded_whole(jpegs: list[bytes]) -> None:
    data = jpegs[0]
    image = decode_compressed(data)
    h, w = image.shape[:2]
    # most of the picture: the whole decode is cheaper
    assert decode_jpeg_region(data, (0, 0, h, w)) is None
    # cut short: the whole decode refuses it, wherever the cut lies
    assert decode_jpeg_region(data[: len(data) * 3 // 4], (0, 0, 16, 16)) is None
    # progressive: decoded whole
    progressive = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    assert decode_jpeg_region(progressive, (0, 0, 16, 16)) is None
    # not a JPEG at all
    assert decode_jpeg_region(b"\xff\xd8garbage\xff\xd9", (0, 0, 16, 16)) is None
    # a picture simplejpeg would refuse still gets its refusal from the whole decode
    with pytest.raises(ValueError):
        simplejpeg.decode_jpeg(data[:100])


@pytest.fixture(scope="module")
def pictures() -> list[av.VideoFrame]:
    paths = _frames(*SEQUENCES[0])[:8]
    units = encode_video([cv2.imread(str(p)) for p in paths])
    dec = av.CodecContext.create("h264", "r")
    return [f for u in units for f in dec.decode(av.Packet(u))]


def test_an_h264_region_converts_to_the_whole_pictures_pixels(pictures) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(5)
    for picture in pictures:
        assert converts_by_region(picture)
        whole = picture_bgr(picture)
        for region in _random_regions(rng, picture.height, picture.width, 5):
            got = picture_bgr_region(picture, region)
            assert isinstance(got, RegionFrame)
            assert contains(got.region, region) and got.pixels.shape == whole.shape
            t, lf, b, r = got.region
            np.testing.assert_array_equal(got.pixels[t:b, lf:r], whole[t:b, lf:r])
        assert isinstance(picture_bgr_region(picture, None), np.ndarray)


def test_pictures_of_other_colours_are_converted_whole_by_ffmpeg(pictures) -> None:  # type: ignore[no-untyped-def]
    full_range = pictures[0].reformat(format="yuvj420p")
    assert not converts_by_region(full_range)
    got = picture_bgr_region(full_range, (0, 0, 16, 16))
    np.testing.assert_array_equal(got, full_range.to_ndarray(format="bgr24"))
