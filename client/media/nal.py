"""H.264 / H.265 access units as NAL units (Annex B byte streams): which types start a
picture or carry parameter sets, and the units of one access unit, found without decoding.
Codecs are named as FFmpeg names them (``"h264"``, ``"hevc"``); the wire's names map to these
in the encoding table (:mod:`.encodings`)."""

from __future__ import annotations

#: Annex B NAL unit types: keyframes (H.264 IDR 5; H.265 IRAP 16-21) and parameter sets
#: (H.264 SPS 7, PPS 8; H.265 VPS 32, SPS 33, PPS 34)
KEYFRAME_TYPES = {"h264": frozenset({5}), "hevc": frozenset(range(16, 22))}
PARAMETER_TYPES = {"h264": frozenset({7, 8}), "hevc": frozenset({32, 33, 34})}
#: The most NAL units one access unit may hold. A camera's picture has a handful (parameter
#: sets, SEI, its slices; a low-latency encoder's size-capped slices a few hundred at 4K).
#: Every start code costs FFmpeg per-unit state, and a Python loop an iteration, so a unit
#: packed with them is refused after reading this many, whatever its size.
MAX_NAL_UNITS = 1024


def nal_units(data: bytes, codec: str, limit: int = MAX_NAL_UNITS) -> list[tuple[int, bytes]]:
    """The NAL units of an Annex B access unit: (type, the unit with its start code).

    Raises ``ValueError`` at the ``limit + 1``-th start code: the search (bytes.find, in C) is
    linear in the unit's size and stops there, so a unit packed with start codes costs at
    most ``limit`` steps of Python."""
    starts: list[tuple[int, int]] = []
    i = data.find(b"\x00\x00\x01")
    while i >= 0:
        if len(starts) == limit:
            raise ValueError(f"more than {limit} NAL units in one access unit")
        begin = i - 1 if i > 0 and data[i - 1] == 0 else i  # a 4-byte start code
        starts.append((begin, i + 3))
        i = data.find(b"\x00\x00\x01", i + 3)
    units = []
    for k, (begin, payload) in enumerate(starts):
        end = starts[k + 1][0] if k + 1 < len(starts) else len(data)
        if payload >= end:
            continue
        header = data[payload]
        kind = header & 0x1F if codec == "h264" else (header >> 1) & 0x3F
        units.append((kind, data[begin:end]))
    return units
