"""The C region decoder's own checks (``client/media/_jpegregion.c``), one case each: the buffer's
size, the rectangle's clamping and refusal, the pictures it leaves to the whole decode, and
libjpeg's errors and warnings coming back through ``longjmp`` as ``ValueError``.
``fuzz/sanitize.py`` runs these on the AddressSanitizer / UBSan build too."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from arcf.client.media.images import REGION_DECODING

pytestmark = pytest.mark.skipif(not REGION_DECODING, reason="the C module is not built")

CORPUS = Path(__file__).resolve().parents[2] / "fuzz" / "corpus" / "jpeg_region"


def jpeg(name: str) -> bytes:
    return (CORPUS / name).read_bytes()[8:]  # the seed without its rectangle


@pytest.fixture(scope="module")
def jr():  # type: ignore[no-untyped-def]
    from arcf.client.media import _jpegregion  # type: ignore[attr-defined]

    return _jpegregion


def test_the_sanitized_build_is_the_one_under_test(jr) -> None:  # type: ignore[no-untyped-def]
    built = os.environ.get("ARCF_SANITIZED_JPEGREGION")
    if built is None:
        pytest.skip("not run by fuzz/sanitize.py")
    assert Path(jr.__file__).resolve() == Path(built).resolve()


def test_header_reads_the_size_components_and_mode(jr) -> None:  # type: ignore[no-untyped-def]
    assert jr.header(jpeg("baseline"))[:3] == (64, 48, 3)
    assert jr.header(jpeg("grey"))[:3] == (64, 48, 1)
    assert jr.header(jpeg("progressive"))[4] == 1


@pytest.mark.parametrize("data", [b"", b"\xff\xd8", b"not a jpeg", b"\xff\xd8\xff\xc0\x00"])
def test_header_refuses_what_is_not_a_jpeg(jr, data: bytes) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError):
        jr.header(data)


def test_a_whole_rectangle_decodes_every_pixel(jr) -> None:  # type: ignore[no-untyped-def]
    out = np.zeros((48, 64, 3), np.uint8)
    assert jr.decode_region(jpeg("baseline"), out, 0, 0, 48, 64) == (0, 0, 48, 64)
    assert out.any()


def test_a_rectangle_past_the_edges_is_clamped(jr) -> None:  # type: ignore[no-untyped-def]
    out = np.zeros((48, 64, 3), np.uint8)
    assert jr.decode_region(jpeg("baseline"), out, -100, -100, 10_000, 10_000) == (0, 0, 48, 64)


def test_a_rectangle_is_widened_to_whole_blocks_and_nothing_else_is_written(jr) -> None:  # type: ignore[no-untyped-def]
    out = np.full((48, 64, 3), 0xA5, np.uint8)
    top, left, bottom, right = jr.decode_region(jpeg("baseline"), out, 20, 20, 30, 30)
    assert top <= 20 and left <= 20 and bottom >= 30 and right >= 30
    assert left % 8 == 0
    outside = np.ones((48, 64), bool)
    outside[top:bottom, left:right] = False
    assert (out[outside] == 0xA5).all()


@pytest.mark.parametrize("rect", [(30, 0, 30, 64), (0, 40, 48, 40), (48, 0, 60, 64),
                                  (0, 64, 48, 80), (-20, -20, -1, -1), (10, 10, 5, 5)])
def test_an_empty_or_outside_rectangle_is_refused(jr, rect) -> None:  # type: ignore[no-untyped-def]
    out = np.zeros((48, 64, 3), np.uint8)
    with pytest.raises(ValueError, match="outside the picture"):
        jr.decode_region(jpeg("baseline"), out, *rect)


@pytest.mark.parametrize("shape", [(48, 64, 1), (48, 63, 3), (47, 64, 3), (0,)])
def test_a_buffer_of_another_size_is_refused(jr, shape) -> None:  # type: ignore[no-untyped-def]
    out = np.zeros(shape, np.uint8)
    with pytest.raises(ValueError, match="not the picture's size"):
        jr.decode_region(jpeg("baseline"), out, 0, 0, 48, 64)


def test_a_read_only_or_strided_buffer_is_refused(jr) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(TypeError):
        jr.decode_region(jpeg("baseline"), bytes(48 * 64 * 3), 0, 0, 48, 64)
    strided = np.zeros((48, 128, 3), np.uint8)[:, ::2]
    with pytest.raises((TypeError, BufferError, ValueError)):
        jr.decode_region(jpeg("baseline"), strided, 0, 0, 48, 64)


@pytest.mark.parametrize(("name", "match"), [
    ("progressive", "progressive or arithmetic"), ("arithmetic", "progressive or arithmetic"),
    ("arithmetic_progressive", "progressive or arithmetic"), ("cmyk", "not a YCbCr or grey"),
    ("rgb", "not a YCbCr or grey"), ("precision_12", "precision"),
    ("sof_height_0", ""), ("truncated_half", ""), ("truncated_half_eoi", ""), ("soi_only", "")])
def test_what_it_does_not_take_comes_back_as_value_error(jr, name: str, match: str) -> None:  # type: ignore[no-untyped-def]
    data = jpeg(name)
    try:
        width, height, components = jr.header(data)[:3]
    except ValueError as exc:  # refused at the header: the longjmp path of header()
        assert str(exc)
        return
    out = np.zeros(width * height * max(components, 1), np.uint8)
    with pytest.raises(ValueError, match=match or None) as info:
        jr.decode_region(data, out, 0, 0, height, width)
    assert str(info.value)


def test_damage_libjpeg_papers_over_is_reported(jr) -> None:  # type: ignore[no-untyped-def]
    """A corrupt entropy-coded segment gives libjpeg a warning, not an error: the decoder
    still refuses (the caller's whole decode decides)."""
    data = bytearray(jpeg("baseline"))
    sos = data.rfind(b"\xff\xda")
    for i in range(sos + 20, len(data) - 2, 7):
        data[i] = 0xFF if data[i + 1] != 0 else data[i]
    out = np.zeros((48, 64, 3), np.uint8)
    with pytest.raises(ValueError):
        jr.decode_region(bytes(data), out, 0, 0, 48, 64)


def test_restart_markers_and_every_sampling_decode(jr) -> None:  # type: ignore[no-untyped-def]
    for name in ("restart_rows", "restart_blocks", "restart_interval_1", "sampling_444",
                 "sampling_422", "sampling_440", "sampling_411", "grey", "sof_1x1"):
        data = jpeg(name)
        width, height, components = jr.header(data)[:3]
        out = np.zeros(width * height * components, np.uint8)
        try:
            got = jr.decode_region(data, out, 0, 0, height, width)
        except ValueError:
            assert name == "sof_1x1"  # a 1x1 header over 64x48 data: damage, refused
            continue
        assert got == (0, 0, height, width), name


@pytest.mark.parametrize("name", ["sof_8000x8000", "sof_65535x65535"])
def test_an_absurd_declared_size_is_refused_before_any_pixel(jr, name: str) -> None:  # type: ignore[no-untyped-def]
    """A huge header over 64 x 48 data: the size check (overflow-safe) refuses any buffer
    that is not the declared picture's, so nothing is written past a small one."""
    data = jpeg(name)
    try:
        width, height = jr.header(data)[:2]
    except ValueError:  # libjpeg's own limit (65500) refuses it first
        return
    out = np.full(64 * 48 * 3 + 64, 0xA5, np.uint8)
    with pytest.raises(ValueError):
        jr.decode_region(data, out[:64 * 48 * 3], 0, 0, height, width)
    assert (out[64 * 48 * 3:] == 0xA5).all()
