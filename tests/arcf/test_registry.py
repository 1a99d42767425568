"""The registry of tracker families: every preset belongs to one family, a family's class is
imported only when built, a new family joins with one entry, and a remote request is checked
by one validator."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from arcf.errors import InvalidParameterError, UnknownPresetError
from arcf.presets import PRESETS, preset_key
from arcf.registry import (
    ALL_PRESETS,
    FAMILIES,
    Family,
    create_tracker,
    family_of,
    preset_params,
    register,
    request_params,
)
from arcf.tracker import ARCFTracker
from arcf.types import TrackResult


def test_every_preset_is_in_exactly_one_family() -> None:
    names = [p.name for f in FAMILIES for p in f.presets]
    assert len(names) == len(set(names))
    assert set(names) == set(ALL_PRESETS)
    assert set(PRESETS) <= set(ALL_PRESETS)
    for name, params in ALL_PRESETS.items():
        assert isinstance(params, family_of(params).params), name


def test_preset_names_are_normalised_in_one_place() -> None:
    assert preset_key("ARCF_HC") == "arcf-hc"
    assert preset_params("ARCF_H") is ALL_PRESETS["arcf-h"]
    assert isinstance(create_tracker("Arcf_H"), ARCFTracker)


def test_listing_presets_imports_no_tracker(loaded_after: Callable[..., list[str]]) -> None:
    assert loaded_after("import arcf.registry as r\nassert 'arcf-nano' in r.ALL_PRESETS",
                        "arcf.tracker", "arcf.siamese", "arcf.hybrid") == []


@dataclass(frozen=True)
class _StillParams:
    name: str
    shift: float = 0.0


class _StillTracker:
    """A family of one test: the box it was given, moved by ``shift`` each frame."""

    def __init__(self, params: _StillParams, *, models_dir: Any = None,
                 colornames_path: Any = None) -> None:
        self.params = params
        self.box = (0.0, 0.0, 0.0, 0.0)
        self.frames = 0

    def init(self, frame: np.ndarray, box: Any) -> TrackResult:
        self.box = tuple(float(v) for v in box)  # type: ignore[assignment]
        return TrackResult(self.box, 1.0, 1.0, 0.0, 0.0, 1.0, 0)

    def update(self, frame: np.ndarray) -> TrackResult:
        self.frames += 1
        x, y, w, h = self.box
        self.box = (x + self.params.shift, y, w, h)
        return TrackResult(self.box, 1.0, 1.0, 0.0, 0.0, 1.0, self.frames)

    def read_region(self) -> None:
        return None


def test_a_new_family_joins_with_one_entry(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("arcf.registry.FAMILIES", list(FAMILIES))
    monkeypatch.setattr("arcf.registry.ALL_PRESETS", dict(ALL_PRESETS))
    register(Family("still", _StillParams, f"{__name__}:_StillTracker",
                    (_StillParams("still-right", shift=2.0),)))
    tracker = create_tracker("still-right")
    frame = np.zeros((20, 30), np.uint8)
    tracker.init(frame, (5, 5, 4, 4))
    assert tracker.update(frame).box == (7.0, 5.0, 4.0, 4.0)
    with pytest.raises(InvalidParameterError, match="takes no overrides"):
        create_tracker("still-right", shift=3.0)
    with pytest.raises(ValueError, match="already registered"):
        register(Family("again", _StillParams, f"{__name__}:_StillTracker",
                        (_StillParams("arcf-h"),)))


def test_a_request_is_checked_by_one_validator() -> None:
    name, params = request_params("ARCF_H", {"gamma": 0.5, "state.reacquire": False})
    assert name == "arcf-h" and params.gamma == 0.5 and params.state.reacquire is False
    with pytest.raises(UnknownPresetError) as unknown:
        request_params("arcf-x", {})
    assert not isinstance(unknown.value, InvalidParameterError)
    for overrides, says in (({"fhog_sse_table": "/etc/passwd"}, "names a file"),
                            ({"gamma": "high"}, "gamma"),
                            ({"no_such": 1}, "unknown parameter"),
                            ({"gamma": 1e9}, r"\[0, 100\]")):
        with pytest.raises(InvalidParameterError, match=says):
            request_params("arcf-h", overrides)
    with pytest.raises(InvalidParameterError, match="takes no overrides"):
        request_params("nanotrack", {"gamma": 1.0})
