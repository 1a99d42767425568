"""Pictures on the wire: the encodings' one table (:mod:`.encodings`), their header readers
(:mod:`.headers`), image decoding whole or by region (:mod:`.images`), H.264 / H.265 streams
(:mod:`.video`) and FFmpeg's pictures as OpenCV's (:mod:`.convert`)."""
