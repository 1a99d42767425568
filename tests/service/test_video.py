"""One stream's H.264 / H.265 decoder: real frames encoded with libx264 / libx265 (PyAV's
wheels), decoded as FFmpeg decodes them when nothing is lost, and resynchronised at the next
keyframe, never smeared, when a unit is lost or damaged."""

from __future__ import annotations

import av
import cv2
import numpy as np
import pytest

from arcf.client.media.convert import picture_bgr
from arcf.client.media.nal import nal_units
from arcf.client.media.video import Outcome, StreamDecoder
from arcf.data import data_root

SEQ = data_root() / "uav123_10fps" / "data_seq" / "wakeboard7"
pytestmark = pytest.mark.skipif(not SEQ.is_dir(), reason="needs ../shared/data")
GOP = 10


def encode(codec: str, n: int, size: tuple[int, int]) -> list[bytes]:
    """The first ``n`` frames of a real sequence as access units (Annex B), a keyframe every
    ``GOP`` frames, no B-frames (a live camera's stream)."""
    enc = av.CodecContext.create(codec, "w")
    enc.width, enc.height = size
    enc.pix_fmt, enc.framerate = "yuv420p", 10
    if codec == "libx264":
        enc.options = {"g": str(GOP), "bf": "0", "preset": "veryfast", "tune": "zerolatency",
                       "sc_threshold": "0"}
    else:
        enc.options = {"x265-params": f"keyint={GOP}:min-keyint={GOP}:bframes=0:scenecut=0:"
                       "log-level=error", "preset": "ultrafast"}
    units = []
    for path in sorted(SEQ.glob("*.jpg"))[:n]:
        image = cv2.resize(cv2.imread(str(path)), size, interpolation=cv2.INTER_AREA)
        units += [bytes(p) for p in enc.encode(av.VideoFrame.from_ndarray(image, "bgr24"))]
    units += [bytes(p) for p in enc.encode(None)]
    assert len(units) == n
    return units


@pytest.fixture(scope="module")
def h264() -> list[bytes]:
    return encode("libx264", 30, (640, 360))


def plain(units: list[bytes], codec: str = "h264") -> list[np.ndarray]:
    ctx = av.CodecContext.create(codec, "r")
    return [picture_bgr(f) for u in units for f in ctx.decode(av.Packet(u))]


def test_an_intact_stream_decodes_as_ffmpeg_does(h264: list[bytes]) -> None:
    dec = StreamDecoder("h264")
    got = [dec.decode(i, u) for i, u in enumerate(h264)]
    assert [g.outcome for g in got] == [Outcome.FRAME] * len(h264)
    for g, want in zip(got, plain(h264), strict=True):
        np.testing.assert_array_equal(g.image, want)
    kinds = [[k for k, _ in nal_units(u, "h264")] for u in h264]
    assert 7 in kinds[0] and 8 in kinds[0] and 5 in kinds[0] and 5 in kinds[GOP]


def test_a_lost_unit_resynchronises_at_the_next_keyframe(h264: list[bytes]) -> None:
    dec = StreamDecoder("h264")
    out = {i: dec.decode(i, u) for i, u in enumerate(h264) if i != 13}
    assert out[14].outcome is Outcome.RESYNC and "lost" in (out[14].reason or "")
    assert all(out[i].outcome is Outcome.WAITING for i in range(15, 2 * GOP))
    assert all(out[i].outcome is Outcome.FRAME for i in range(2 * GOP, len(h264)))
    # from the keyframe on, exactly what a decoder that saw everything gives
    for i, want in zip(range(2 * GOP, len(h264)), plain(h264)[2 * GOP:], strict=True):
        np.testing.assert_array_equal(out[i].image, want)
    assert dec.counts["resync_gap"] == 1 and dec.counts["waiting_for_keyframe"] == 5


def test_a_gap_that_ends_at_a_keyframe_resumes_there(h264: list[bytes]) -> None:
    """A sender that skips the rest of a damaged group of pictures (arcf-ingest does) sends
    the next keyframe right after the hole: decoded at once, the resynchronisation counted."""
    dec = StreamDecoder("h264")
    out = {i: dec.decode(i, u) for i, u in enumerate(h264) if not GOP + 3 <= i < 2 * GOP}
    assert out[2 * GOP].outcome is Outcome.FRAME and out[2 * GOP].resynced == "gap"
    assert all(out[i].outcome is Outcome.FRAME and out[i].resynced is None
               for i in out if i != 2 * GOP)
    for i, want in zip(range(2 * GOP, len(h264)), plain(h264)[2 * GOP:], strict=True):
        np.testing.assert_array_equal(out[i].image, want)
    assert dec.counts["resync_gap"] == 1 and dec.counts.get("waiting_for_keyframe", 0) == 0


def test_a_damaged_unit_is_not_decoded_into_a_smeared_picture(h264: list[bytes]) -> None:
    dec = StreamDecoder("h264")
    broken = bytearray(h264[13])
    broken[len(broken) // 2:len(broken) // 2 + 40] = bytes(40)
    units = [*h264[:13], bytes(broken), *h264[14:]]
    out = [dec.decode(i, u) for i, u in enumerate(units)]
    assert out[13].outcome is Outcome.RESYNC and "damaged" in (out[13].reason or "")
    assert all(o.outcome is Outcome.WAITING for o in out[14:2 * GOP])
    assert all(o.outcome is Outcome.FRAME for o in out[2 * GOP:])
    assert dec.counts["resync_corrupt"] == 1
    # junk: no start code, or start codes and noise; never a crash, never a frame
    junk = StreamDecoder("h264")
    assert junk.decode(0, b"not video").outcome is Outcome.RESYNC
    noise = np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8).tobytes()
    assert junk.decode(1, b"\x00\x00\x00\x01\x65" + noise).outcome in (Outcome.RESYNC,
                                                                       Outcome.NO_FRAME)
    assert junk.decode(2, h264[1]).outcome in (Outcome.WAITING, Outcome.RESYNC)


def test_joining_mid_stream_and_keyframes_without_parameter_sets(h264: list[bytes]) -> None:
    dec = StreamDecoder("h264")
    assert dec.decode(0, h264[0]).outcome is Outcome.FRAME  # learns SPS / PPS
    # lost until a keyframe that carries no parameter sets: they are put back in front
    bare = b"".join(u for k, u in nal_units(h264[GOP], "h264") if k not in (7, 8))
    assert dec.decode(5, h264[5]).outcome is Outcome.RESYNC
    got = dec.decode(GOP, bare)
    assert got.outcome is Outcome.FRAME
    np.testing.assert_array_equal(got.image, plain(h264)[GOP])
    late = StreamDecoder("h264")  # joined after the start: nothing before a keyframe
    assert late.decode(3, h264[3]).outcome is Outcome.WAITING
    assert late.decode(GOP, h264[GOP]).outcome is Outcome.FRAME  # parameter sets in it


def test_h265() -> None:
    units = encode("libx265", 12, (320, 192))
    dec = StreamDecoder("hevc")
    got = [dec.decode(i, u) for i, u in enumerate(units)]
    assert [g.outcome for g in got] == [Outcome.FRAME] * 12
    for g, want in zip(got, plain(units, "hevc"), strict=True):
        np.testing.assert_array_equal(g.image, want)
    with pytest.raises(ValueError):
        StreamDecoder("vp9")


def test_pictures_above_max_pixels_are_refused_before_decoding(h264: list[bytes]) -> None:
    dec = StreamDecoder("h264", max_pixels=640 * 360 - 1)  # one pixel short of the stream's
    out = [dec.decode(i, u) for i, u in enumerate(h264[:GOP + 1])]
    assert out[0].outcome is Outcome.RESYNC and out[0].cause == "oversized"
    assert out[0].reason == "the stream declares 640x360 pictures, above max_pixels (230399 pixels)"
    assert all(o.outcome is not Outcome.FRAME for o in out)
    assert StreamDecoder("h264", max_pixels=640 * 360).decode(0, h264[0]).outcome is Outcome.FRAME


def test_an_access_unit_packed_with_start_codes_is_refused_before_the_decoder() -> None:
    """2 MiB of bare IDR start codes took FFmpeg's decoder to 1.1 GB; 8 MiB of access-unit
    delimiters cost Python 2M loop steps. Both are refused at MAX_NAL_UNITS + 1 start codes,
    the decoder never made, and a real stream decodes afterwards."""
    from arcf.client.media.nal import MAX_NAL_UNITS

    with pytest.raises(ValueError, match=f"more than {MAX_NAL_UNITS} NAL units"):
        nal_units(b"\x00\x00\x01\x09" * (2 << 20), "h264")
    assert len(nal_units(b"\x00\x00\x01\x09\xf0" * MAX_NAL_UNITS, "h264")) == MAX_NAL_UNITS
    for codec, unit in (("h264", b"\x00\x00\x01\x65"), ("hevc", b"\x00\x00\x01\x26\x01")):
        dec = StreamDecoder(codec)
        out = dec.decode(0, unit * (MAX_NAL_UNITS + 1))
        assert out.outcome is Outcome.RESYNC and out.cause == "corrupt"
        assert f"more than {MAX_NAL_UNITS} NAL units" in (out.reason or "")
        assert not dec.synchronised and dec.counts == {"resync": 1, "resync_corrupt": 1}


def test_pictures_are_converted_only_when_asked_for(h264: list[bytes]) -> None:
    """A unit decoded to keep the chain holds FFmpeg's picture; BGR pixels are made once, on
    first use, equal to FFmpeg's own conversion."""
    dec = StreamDecoder("h264")
    out = dec.decode(0, h264[0])
    assert out.picture is not None and "image" not in out.__dict__
    first = out.image
    assert first is out.image  # converted once
    np.testing.assert_array_equal(first, plain(h264[:1])[0])


def test_a_picture_of_the_last_two_groups_decodes_again_as_it_did_live(
        h264: list[bytes]) -> None:
    """The group since the last keyframe and the one before are kept: any of their pictures
    decodes again, pixel for pixel as the live decoder gave it, each with its unit's tag
    (a box drawn on the last picture before a keyframe comes after it); a keyframe that
    came without its parameter sets still starts a group that decodes on its own."""
    bare = b"".join(u for k, u in nal_units(h264[GOP], "h264") if k not in (7, 8))
    units = [*h264[:GOP], bare, *h264[GOP + 1:]]
    dec = StreamDecoder("h264", history_units=3 * GOP)
    live = [dec.decode(i, u, tag=f"unit {i}") for i, u in enumerate(units[:2 * GOP - 2])]
    assert [u.seq for u in dec.group.units] == list(range(GOP, 2 * GOP - 2))
    assert dec.group.covers(0) and dec.group.covers(2 * GOP - 3)
    again = list(dec.replay(GOP + 3, GOP + 6))
    assert [(d.seq, tag) for d, tag in again] == [(i, f"unit {i}") for i in range(13, 17)]
    across = list(dec.replay(GOP - 2, GOP + 1))  # the last two of a group, the next two
    assert [d.seq for d, _ in again + across] == [13, 14, 15, 16, 8, 9, 10, 11]
    for d, _ in again + across:
        np.testing.assert_array_equal(d.image, live[d.seq or 0].image)
    # the live decoder's state is its own: it goes on where it was
    assert dec.decode(2 * GOP - 2, units[2 * GOP - 2]).outcome is Outcome.FRAME
    for i in range(2 * GOP - 1, 2 * GOP + 2):  # a third group: the first one goes
        dec.decode(i, units[i])
    assert not dec.group.covers(GOP - 1) and dec.group.covers(GOP)
    assert list(dec.replay(GOP - 2, GOP + 1)) == []  # before the kept groups: nothing


def test_the_kept_group_is_bounded_and_dropped_when_the_chain_breaks(
        h264: list[bytes]) -> None:
    short = StreamDecoder("h264", history_units=4)
    for i, u in enumerate(h264[:GOP]):
        short.decode(i, u)
    assert not short.group.covers(0) and short.group.units == []  # outgrew: none kept
    short.decode(GOP, h264[GOP])
    assert short.group.covers(GOP)  # the next keyframe starts a group again
    roomy = StreamDecoder("h264", history_units=GOP + 3)
    for i, u in enumerate(h264[:GOP + 4]):
        roomy.decode(i, u)
    assert not roomy.group.covers(GOP - 1) and roomy.group.covers(GOP)  # the older went
    broken = StreamDecoder("h264", history_units=3 * GOP)
    for i, u in enumerate(h264[:5]):
        broken.decode(i, u)
    assert broken.decode(7, h264[7]).outcome is Outcome.RESYNC  # 5 and 6 lost
    assert broken.group.units == [] and list(broken.replay(0, 4)) == []
    none = StreamDecoder("h264")  # the default: nothing kept
    none.decode(0, h264[0])
    assert none.group.units == [] and list(none.replay(0, 0)) == []


def test_units_before_the_wanted_one_are_kept_from_their_keyframe_not_decoded(
        h264: list[bytes]) -> None:
    """Every session waits for frame 23 (a station's history came first): units before it
    are only kept, from their last keyframe on (20), and decoded with unit 23, which gives
    the picture a decoder that saw everything gives; nothing of groups 0 and 10 is
    decoded."""
    dec = StreamDecoder("h264", history_units=3 * GOP)
    out = [dec.decode(i, u, tag=i, wanted_from=23) for i, u in enumerate(h264[:23])]
    assert {o.outcome for o in out} == {Outcome.NO_FRAME}
    assert dec.counts == {"deferred": 23}
    got = dec.decode(23, h264[23], tag=23, wanted_from=23)
    assert got.outcome is Outcome.FRAME and got.seq == 23
    np.testing.assert_array_equal(got.image, plain(h264)[23])
    assert dec.counts["frame"] == 4  # 20, 21, 22 and 23
    assert [u.seq for u in dec.group.units] == [20, 21, 22, 23]
    assert [d.seq for d, _ in dec.replay(21, 22)] == [21, 22]  # the kept group replays
    # a unit lost while waiting: what was kept is dropped, the next keyframe starts again
    lossy = StreamDecoder("h264", history_units=3 * GOP)
    for i in (*range(12), *range(13, 15)):
        lossy.decode(i, h264[i], wanted_from=15)
    assert lossy.decode(15, h264[15], wanted_from=15).outcome is Outcome.WAITING
