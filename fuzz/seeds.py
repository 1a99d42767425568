"""Write the fuzz targets' seed corpus (``fuzz/corpus/<target>/``): what the fuzzer starts
from and what ``tests/service/test_fuzz_corpus.py`` replays on every run.

The seeds are small (64 x 48 pictures) real files: baseline, grey, progressive,
arithmetic-coded, restart markers, CMYK, 4:2:0 / 4:2:2 / 4:4:0 sampling, truncated, 12-bit and
absurd SOF sizes (a baseline file with its SOF patched); PNGs; every message type; real H.264
and H.265 access units (PyAV's encoders) and CDR of each type the bridge reads. Arithmetic
coding and restart markers need libjpeg-turbo's ``cjpeg`` (Debian's libjpeg-turbo-progs); the
files are kept in the repository, so only regenerating them needs it.

    python fuzz/seeds.py            # rewrite fuzz/corpus/
"""

from __future__ import annotations

import base64
import hashlib
import io
import shutil
import struct
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path
from typing import Any

import cv2
import numpy as np

CORPUS = Path(__file__).resolve().parent / "corpus"


def _picture(channels: int = 3) -> np.ndarray:
    """A 64 x 48 gradient with edges, so that every block has AC coefficients."""
    y, x = np.mgrid[0:48, 0:64]
    bgr = np.stack([(x * 4) % 256, (y * 5) % 256, ((x ^ y) * 8) % 256], -1).astype(np.uint8)
    return bgr if channels == 3 else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)


def _sof(jpeg: bytes) -> int:
    """The offset of the first SOF marker."""
    i = 2
    while i + 4 <= len(jpeg):
        marker = jpeg[i + 1]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return i
        i += 2 + struct.unpack(">H", jpeg[i + 2:i + 4])[0]
    raise ValueError("no SOF")


def _patched(jpeg: bytes, offset: int, value: bytes) -> bytes:
    return jpeg[:offset] + value + jpeg[offset + len(value):]


def jpegs() -> Iterator[tuple[str, bytes]]:
    from PIL import Image

    bgr, grey = _picture(), _picture(1)
    base = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
    yield "baseline", base
    yield "grey", cv2.imencode(".jpg", grey)[1].tobytes()
    for name, sampling in (("444", cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444),
                           ("422", cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422),
                           ("440", cv2.IMWRITE_JPEG_SAMPLING_FACTOR_440),
                           ("411", cv2.IMWRITE_JPEG_SAMPLING_FACTOR_411)):
        yield f"sampling_{name}", cv2.imencode(
            ".jpg", bgr, [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, sampling])[1].tobytes()
    yield "restart_interval_1", cv2.imencode(
        ".jpg", bgr, [cv2.IMWRITE_JPEG_RST_INTERVAL, 1])[1].tobytes()
    # a restart interval per MCU row, on a picture tall enough for the decoder to start at
    # one (every 64 rows of this 4:4:4 one, every 128 of the 4:2:0)
    tall = np.concatenate([bgr] * 6)  # 64 x 288
    for name, sampling, per_row in (("444", cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444, 8),
                                    ("420", cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420, 4)):
        yield f"restart_rows_tall_{name}", cv2.imencode(
            ".jpg", tall, [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, sampling,
                           cv2.IMWRITE_JPEG_RST_INTERVAL, per_row])[1].tobytes()
    rgb = Image.fromarray(bgr[..., ::-1])
    for name, image, options in (("progressive", rgb, {"progressive": True}),
                                 ("cmyk", rgb.convert("CMYK"), {}),
                                 ("optimized", rgb, {"optimize": True})):
        out = io.BytesIO()
        image.save(out, "JPEG", **options)
        yield name, out.getvalue()
    if shutil.which("cjpeg"):
        with tempfile.TemporaryDirectory() as tmp:
            ppm = Path(tmp) / "in.ppm"
            cv2.imwrite(str(ppm), bgr)
            for name, flags in (("arithmetic", ["-arithmetic"]),
                                ("arithmetic_progressive", ["-arithmetic", "-progressive"]),
                                ("restart_rows", ["-restart", "1"]),
                                ("restart_blocks", ["-restart", "3B"]),
                                ("rgb", ["-rgb"]), ("smooth", ["-smooth", "30"])):
                yield name, subprocess.run(["cjpeg", *flags, str(ppm)], check=True,
                                           capture_output=True).stdout
    else:
        print("no cjpeg (libjpeg-turbo-progs): arithmetic and restart seeds skipped",
              file=sys.stderr)
    sof = _sof(base)
    yield "precision_12", _patched(base, sof + 4, b"\x0c")
    yield "sof_65535x65535", _patched(base, sof + 5, struct.pack(">HH", 65535, 65535))
    yield "sof_height_0", _patched(base, sof + 5, struct.pack(">H", 0))
    yield "sof_1x1", _patched(base, sof + 5, struct.pack(">HH", 1, 1))
    yield "sof_8000x8000", _patched(base, sof + 5, struct.pack(">HH", 8000, 8000))
    yield "truncated_half", base[:len(base) // 2]
    yield "truncated_half_eoi", base[:len(base) // 2] + b"\xff\xd9"
    yield "no_eoi", base[:-2]
    yield "soi_only", b"\xff\xd8"


def pngs() -> Iterator[tuple[str, bytes]]:
    yield "png", cv2.imencode(".png", _picture())[1].tobytes()
    yield "png_grey16", cv2.imencode(".png", (_picture(1).astype(np.uint16) * 257))[1].tobytes()
    png = cv2.imencode(".png", _picture())[1].tobytes()
    yield "png_huge_ihdr", png[:16] + struct.pack(">II", 100_000, 100_000) + png[24:]


def messages() -> Iterator[tuple[str, bytes]]:
    from arcf.schemas import (
        Ack,
        ErrorCode,
        ErrorMessage,
        Frame,
        PresetsRequest,
        ReinitRequest,
        StartRequest,
        StatusRequest,
        StopRequest,
        encode,
    )

    jpeg = cv2.imencode(".jpg", _picture())[1].tobytes()
    yield "frame_jpeg", encode(Frame(stream_id="cam-1", seq=3, capture_ts_ns=1,
                                     encoding="jpeg", payload=jpeg))
    yield "frame_gray8", encode(Frame(stream_id="cam-1", seq=0, capture_ts_ns=1,
                                      encoding="gray8", width=64, height=48,
                                      payload=_picture(1).tobytes()))
    yield "start", encode(StartRequest(request_id="r1", stream_id="cam-1",
                                       box=(10, 10, 20, 20), preset="arcf-hc",
                                       overrides={"admm_iterations": 2}))
    yield "reinit", encode(ReinitRequest(request_id="r2", session_id="s-1", box=(1, 2, 3, 4)))
    yield "stop", encode(StopRequest(request_id="r3", session_id="s-1"))
    yield "status_request", encode(StatusRequest(request_id="r4"))
    yield "presets_request", encode(PresetsRequest(request_id="r5"))
    yield "ack", encode(Ack(request_id="r3", message="stopped"))
    yield "error", encode(ErrorMessage(code=ErrorCode.DECODE_ERROR, message="bad"))
    yield "result", encode(_result())


def _result() -> Any:
    from arcf.schemas import Result

    return Result(session_id="s-1", stream_id="cam-1", frame_seq=4, capture_ts_ns=5,
                  box=(11.0, 21.0, 30.0, 40.0), peak=0.5, psr=9.0, aberrance=0.01,
                  aberrance_release=0.02, scale=1.0, confidence=0.875, track_state="tracking",
                  status="tracking", dropped=0, received_ts_ns=6, decode_s=0.001,
                  track_s=0.002, published_ts_ns=7)


def access_units(codec: str) -> list[bytes]:
    """A keyframe with its parameter sets, then P-frames, from FFmpeg's encoder (PyAV)."""
    import av

    ctx = av.CodecContext.create("libx264" if codec == "h264" else "libx265", "w")
    ctx.width, ctx.height = 64, 48
    ctx.pix_fmt, ctx.framerate = "yuv420p", Fraction(10)
    ctx.options = ({"bf": "0", "preset": "ultrafast", "tune": "zerolatency"} if codec == "h264"
                   else {"x265-params": "bframes=0:log-level=error", "preset": "ultrafast"})
    units: list[bytes] = []
    for i in range(4):
        frame = av.VideoFrame.from_ndarray(np.roll(_picture(), 4 * i, axis=1), "bgr24")
        units += [bytes(p) for p in ctx.encode(frame)]
    units += [bytes(p) for p in ctx.encode(None)]
    return units


def videos() -> Iterator[tuple[str, bytes]]:
    for flag, codec in ((b"\x00", "h264"), (b"\x01", "hevc")):
        units = access_units(codec)
        yield f"{codec}_stream", flag + b"AU--".join(units)
        yield f"{codec}_keyframe", flag + units[0]
        yield f"{codec}_keyframe_truncated", flag + units[0][:len(units[0]) // 2]
        yield f"{codec}_gap", flag + b"AU--".join([units[0], units[2]])


def cdrs() -> Iterator[tuple[str, bytes]]:
    from arcf.adapters import ros2_types as rt
    from arcf.client.foxglove import compressed_video

    jpeg = cv2.imencode(".jpg", _picture())[1].tobytes()
    header = rt.message("std_msgs/msg/Header", stamp=rt.TYPES.time(1_700_000_000_123_456_789),
                        frame_id="camera")
    image = rt.message(rt.COMPRESSED_IMAGE, header=header, format="jpeg",
                       data=np.frombuffer(jpeg, np.uint8))
    yield "compressed_image", b"\x00" + rt.serialize(image, rt.COMPRESSED_IMAGE)
    from arcf.adapters.ros2 import detection_array
    array = detection_array(_result(), (1_700_000_000_000_000_000, "camera"))
    yield "detection", b"\x01" + rt.serialize(array.detections[0], rt.DETECTION_2D)
    yield "compressed_video", b"\x02" + compressed_video(access_units("h264")[0], "h264",
                                                         1_700_000_000_000_000_000, "camera")


#: Inputs the fuzzer found that broke a contract, kept as seeds once fixed (target -> name,
#: base64): each is replayed on every run of the tests.
FOUND: dict[str, list[tuple[str, str]]] = {
    # an arithmetic-coded JPEG whose header declares colour space 6: simplejpeg's header
    # reader raised KeyError (client/media/images.py now leaves such a picture to OpenCV)
    "image": [("found_simplejpeg_unknown_colorspace",
               "Av/Y/+AAEEpGSUYAAQEAAMIAAQAA/9sAQwAIBgYHCQUHBgcJBwgICgwUDQwLCwwZEhMPFB0aHx4dGhwc"
               "JCQuJyAiLCMcHCg3KSwwMTQ0NB8nOT04MjwuMzQy/9sAQwEJCQkMCwwYDQ0YMiEcITIyMjIyMjIyMjIy"
               "MjIyMjIyMjMyMjIyMjIyMjIyMjIyMjIyMjExMTExMTExMTExMTEx/8kAEQgAMABAAwEUAAIRAQMRAf/a"
               "AAwDAQACEQO/HLIC/0o=")],
    # a JPEG cut inside its headers, with restart intervals of whole rows: the restart seek
    # took the end of libjpeg's own fake end marker for the end of the headers (ASan; fixed
    # before it shipped)
    "jpeg_region": [("found_restart_seek_truncated_header",
                     "QAA1AMAAwAD/2P/gABBKRklGAAH//////////////////////wAA/9sAQwACAQEBAQECAQEBAgICAgcKCgoK"
                     "CgoKCgoKCgoKCgoKCgoKCgoKCgoKCgoKCgoKCgoKCgoKCgoKCgoKCgoKCgoKCv/AABEIASAAQAMBEQACEQED"
                     "EQH/xAAfAAABBQEBAQEBAQAAAAAAAAAAAT0AAAAAAAABPQMEBQYHCAkKC//EALUQAAIBAwMCBAMFBQQEAAAB"
                     "fQECAwAEEQUSITBBBhNRYQcmcRShCCNCscEVUtHwJDNicoIJChYXGBkaJSYnKCkqNDU2Nzg5OkNEf///////"
                     "////////////////////////////////////////////////////////////////////RUZHSElKU1RVVldY"
                     "WVpjZGVmZ2hpOXN0dXZ3eHl6g4SFhoeIiYqSk5QCBAQDBAcFBAQAAQJ3AAECAxEEBSExcWEHQQYSEwMEBQYH"
                     "CAkKC//EALUQAAIBAwMCBAMFBQQEAAABfQECAwAEEQUSITBBBhNRYQcmcRShCCNCscEVUtHwJDNicoIJChYX"
                     "GBkaJSYnKCkqNDU2Nzg5OkNEf///////////////////////////////////////////////////////////"
                     "////////////////RUZHSElKU1RVVldYWVpjZGVmZ2hpOXN0dXZ3eHl6g4SFhoeIiYqSk5QCBAQDBAcFBAQA"
                     "AQJ3AAECAxEEBSExcWEHQQYSE0EiMoEIUvAVYufq8vP09fb3+Pn6/90ABAAI/9oADAMBAAIRAxEA2Q==")],
}


def corpus() -> dict[str, list[tuple[str, bytes]]]:
    """target -> (seed name, bytes): the made seeds, then what fuzzing found (``FOUND``)."""
    made = _made()
    for target, found in FOUND.items():
        made[target] += [(name, base64.b64decode(text)) for name, text in found]
    return made


def _made() -> dict[str, list[tuple[str, bytes]]]:
    images = [*jpegs(), *pngs()]
    jpeg_only = [(n, d) for n, d in images if not n.startswith("png")]
    # jpeg_region: the rectangle's fractions, then the picture
    rect = struct.pack(">4H", 16384, 16384, 49152, 49152)
    whole = struct.pack(">4H", 0, 0, 65535, 65535)
    return {
        "jpeg_region": [(n, rect + d) for n, d in jpeg_only]
        + [("baseline_whole", whole + dict(jpeg_only)["baseline"])],
        "image": [(n + ("_region" if k else ""), bytes([int(n.startswith("png")) | 2 * k]) + d)
                  for n, d in images for k in (0, 1)],
        "message": list(messages()),
        "video": list(videos()),
        "cdr": list(cdrs()),
        "frame_size": [(n, bytes([int(n.startswith("png"))]) + d) for n, d in images],
    }


def main() -> None:
    for target, seeds in corpus().items():
        folder = CORPUS / target
        if folder.is_dir():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        for name, data in seeds:
            (folder / f"{name}").write_bytes(data)
        digest = hashlib.sha256(b"".join(d for _, d in seeds)).hexdigest()[:12]
        print(f"{target}: {len(seeds)} seeds, {sum(len(d) for _, d in seeds)} bytes ({digest})")


if __name__ == "__main__":
    main()
