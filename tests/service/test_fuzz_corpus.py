"""The fuzz targets' seed corpus (``fuzz/corpus/``) replayed through the targets: every seed
keeps every contract (``fuzz/targets.py``), and the corpus holds the kinds of input the
targets must start from. ``fuzz/sanitize.py`` runs this file on the sanitized decoder too."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

FUZZ = Path(__file__).resolve().parents[2] / "fuzz"
sys.path.insert(0, str(FUZZ))
from targets import TARGETS, ContractBroken, jpeg_region  # noqa: E402

SEEDS = [(name, path) for name in TARGETS for path in sorted((FUZZ / "corpus" / name).iterdir())]


@pytest.mark.parametrize(("target", "seed"), SEEDS, ids=[f"{t}/{p.name}" for t, p in SEEDS])
def test_every_seed_keeps_its_targets_contract(target: str, seed: Path) -> None:
    TARGETS[target](seed.read_bytes())


def test_the_corpus_holds_the_pictures_a_decoder_must_survive() -> None:
    names = {p.name for p in (FUZZ / "corpus" / "jpeg_region").iterdir()}
    for kind in ("baseline", "grey", "progressive", "arithmetic", "cmyk", "precision_12",
                 "restart_rows", "restart_interval_1", "sof_65535x65535", "sof_height_0",
                 "truncated_half", "sampling_440"):
        assert kind in names
    for target in TARGETS:
        assert len(list((FUZZ / "corpus" / target).iterdir())) >= 3, target


def test_a_write_outside_the_rectangle_breaks_the_contract(monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """The guard can fail: a decoder that writes one pixel outside what it returns is caught."""
    from arcf.client.media import _jpegregion  # type: ignore[attr-defined]

    real = _jpegregion.decode_region

    def leaky(data: bytes, out, top: int, left: int, bottom: int, right: int):  # type: ignore[no-untyped-def]
        got = real(data, out, top, left, bottom, right)
        out[-1] = 0  # the last row: below the rectangle asked for
        return got

    monkeypatch.setattr(_jpegregion, "decode_region", leaky)
    with pytest.raises(ContractBroken, match="pixels written outside"):
        jpeg_region((FUZZ / "corpus" / "jpeg_region" / "baseline").read_bytes())
