"""`arcf eval report` end to end on one real sequence: tables, Table 2, plots, links."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from arcf.data import data_root
from arcf.eval.paper import build_report
from arcf.eval.runner import TrackerSpec

DATA = data_root()
pytestmark = pytest.mark.skipif(
    not (DATA / "published_results").is_dir() or not (DATA / "uav123_10fps").is_dir(),
    reason=f"needs the shared data under {DATA}",
)


def test_report_on_one_sequence(tmp_path: Path) -> None:
    doc = build_report(
        out=tmp_path / "results",
        doc=tmp_path / "docs" / "results.md",
        img=tmp_path / "docs" / "img",
        jobs=1,
        progress=False,
        configs=(TrackerSpec("bacf", {}, "bacf (ours)"),),
        only=["wakeboard7"],
    )
    text = doc.read_text()
    # 1. the published trackers on the full benchmarks: ARCF-HC's headline figures
    assert "| ARCF-HC |" in text
    assert "0.473" in text and "0.696" in text and "0.720" in text
    # 2. our run next to the published trackers on the same sequence
    assert "bacf (ours)" in text
    assert "wakeboard7" in text
    # 3. Table 2 from the authors' files reproduces the paper's UAV123@10fps figures
    assert "0.0106" in text and "0.0133" in text
    # every linked image exists and is a PNG
    links = re.findall(r"!\[\]\(([^)]+)\)", text)
    assert len(links) >= 9  # 3 datasets x 2 full plots, 2 local plots, 1 map-difference plot
    for link in links:
        png = (doc.parent / link).resolve()
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", link
