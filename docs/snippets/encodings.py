"""The wire's encodings, one table: a real frame through every picture encoding and back, as
a sender encodes it and a worker checks and decodes it; the video encodings' FFmpeg names."""

from types import SimpleNamespace

import cv2

from arcf.client.media.encodings import ENCODINGS, decode_image, encode_image
from arcf.data import data_root

image = cv2.imread(str(data_root() / "uav123_10fps/data_seq/boat1/000001.jpg"))
h, w = image.shape[:2]
for encoding, codec in ENCODINGS.items():
    if codec.is_video:  # one stateful decoder per stream, not one picture at a time
        print(f"{encoding.value}: video, FFmpeg {codec.decoder_name} / {codec.encoder_name}, "
              f"keyframe NAL types {sorted(codec.keyframe_types)}")
        continue
    pixels = image if encoding.value != "gray8" else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    payload = encode_image(pixels, encoding, quality=90)  # what the SDK sends
    size = codec.read_size(payload) if codec.read_size else (w, h)  # header, or declared
    frame = SimpleNamespace(encoding=encoding, payload=payload, width=w, height=h)
    decoded, problem = decode_image(frame, max_pixels=w * h)  # as a worker decodes it
    print(f"{encoding.value}: {codec.kind}, {len(payload)} bytes, size {size}, "
          f"decoded {decoded.shape if problem is None else problem}")
