"""A drone camera's video, made from a sequence's frames: H.264 / H.265 access units as a live
encoder sends them (libx264 / libx265, which PyAV ships in its wheels), and the pictures a
decoder that received every unit gives back (what "the library on the decoded frames" means
in the tests and benchmarks)."""

from __future__ import annotations

from collections.abc import Iterable
from fractions import Fraction
from typing import cast

import av
import numpy as np

from arcf.client.media.convert import picture_bgr
from arcf.client.media.encodings import codec_of
from arcf.client.media.video import padded_packet


def encode_video(images: Iterable[np.ndarray], codec: str = "h264", fps: int = 30,
                 gop: int = 30, crf: int = 23, repeat_headers: bool = False) -> list[bytes]:
    """BGR ``(H, W, 3)`` uint8 images as Annex B access units, one per image: a keyframe
    every ``gop`` images, no B-frames, no scene-cut keyframes (a live camera's low-latency
    stream, whose keyframes come at a fixed interval). ``repeat_headers``: the parameter
    sets in front of every keyframe, not only the first (what a camera streaming to
    receivers that join at any time sends)."""
    encoder_name = codec_of(codec).encoder_name
    enc: av.VideoCodecContext | None = None
    units: list[bytes] = []
    for image in images:
        if enc is None:
            enc = cast(av.VideoCodecContext, av.CodecContext.create(encoder_name, "w"))
            enc.height, enc.width = image.shape[:2]
            enc.pix_fmt, enc.framerate = "yuv420p", Fraction(fps)
            if codec == "h264":
                enc.options = {"g": str(gop), "bf": "0", "preset": "veryfast",
                               "tune": "zerolatency", "sc_threshold": "0", "crf": str(crf),
                               "threads": "1",  # one slice per picture, as cameras send
                               **({"x264-params": "repeat-headers=1"} if repeat_headers
                                  else {})}
            else:
                enc.options = {"preset": "ultrafast", "crf": str(crf),
                               "x265-params": f"keyint={gop}:min-keyint={gop}:bframes=0:"
                                              "scenecut=0:log-level=error"
                                              + (":repeat-headers=1" if repeat_headers
                                                 else "")}
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="bgr24")
        units += [bytes(p) for p in enc.encode(frame)]
    if enc is not None:
        units += [bytes(p) for p in enc.encode(None)]
    return units


def decode_video(units: Iterable[bytes], codec: str = "h264") -> list[np.ndarray]:
    """Every picture of a stream of access units, by one plain FFmpeg decoder, as BGR
    converted as a worker converts it (``picture_bgr``)."""
    dec = cast(av.VideoCodecContext, av.CodecContext.create(codec_of(codec).decoder_name, "r"))
    return [picture_bgr(f) for u in units for f in dec.decode(padded_packet(u))]
