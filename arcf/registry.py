"""The registry of tracker families and their presets: which class a preset's parameters build.

A *family* is one tracker class and the parameter type it takes; a *preset* is a named,
immutable parameter set of a family (:mod:`arcf.presets`). The registry is the one place that
ties them, by name, as pytracking and uvicorn choose implementations: a family names its class
as ``"module:Class"``, imported only when its first tracker is built, so that listing the
presets (a service answering ``presets_request``, ``arcf --help``) loads no network and no
compiled kernel, and so that the tracker modules need not know each other.

A new family joins with one :class:`Family` entry in :data:`FAMILIES` (or :func:`register`
from outside the package): its parameter dataclass (with a ``name``), its presets, and a
tracker class that takes ``(params, *, models_dir=None, colornames_path=None)`` and offers
:class:`arcf.types.Tracker`'s ``init`` / ``update`` / ``read_region``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import InvalidParameterError, UnknownPresetError
from .presets import (
    ARCF_NANO,
    HOST_PARAMETERS,
    NANOTRACK,
    PRESETS,
    VITTRACK,
    HybridParams,
    SiameseParams,
    TrackerParams,
    make_params,
    preset_key,
)
from .types import Tracker

#: Any family's parameters (each a frozen dataclass with a ``name``).
Params = TrackerParams | SiameseParams | HybridParams


@dataclass(frozen=True)
class Family:
    """One tracker class, the parameter type it takes, and its presets."""

    name: str
    #: the parameter dataclass of the family: a preset is one instance of it
    params: type
    #: the tracker class, as ``"module:Class"`` (imported when the first tracker is built)
    tracker: str
    presets: tuple[Any, ...]
    #: how keyword overrides apply to a preset (``None``: the family takes none; its
    #: parameters are, e.g., a network's and OpenCV's)
    override: Callable[..., Any] | None = None

    def tracker_class(self) -> type:
        module, _, attribute = self.tracker.partition(":")
        cls: type = getattr(importlib.import_module(module), attribute)
        return cls


#: Every family the library ships.
FAMILIES: list[Family] = [
    # ARCF's presets are those make_params overrides by name (arcf.presets.PRESETS)
    Family("arcf", TrackerParams, "arcf.tracker:ARCFTracker", tuple(PRESETS.values()),
           override=make_params),
    Family("siamese", SiameseParams, "arcf.siamese:SiameseTracker", (NANOTRACK, VITTRACK)),
    Family("hybrid", HybridParams, "arcf.hybrid:HybridTracker", (ARCF_NANO,)),
]

#: Every preset a tracker can be created from, by name (kept in step by :func:`register`).
ALL_PRESETS: dict[str, Any] = {}


def register(family: Family) -> None:
    """Add a family and its presets; a preset name already taken is refused."""
    taken = sorted(set(ALL_PRESETS) & {p.name for p in family.presets})
    if taken:
        raise ValueError(f"preset name(s) {taken} already registered")
    if family not in FAMILIES:
        FAMILIES.append(family)
    ALL_PRESETS.update({p.name: p for p in family.presets})


for _family in list(FAMILIES):
    register(_family)


def family_of(params: Any) -> Family:
    """The family whose parameter type ``params`` is."""
    for family in FAMILIES:
        if isinstance(params, family.params):
            return family
    raise UnknownPresetError(f"no tracker family takes {type(params).__name__}")


def preset_params(preset: str | Params, **overrides: Any) -> Any:
    """A preset's parameters (by name or as parameters) with its family's overrides applied;
    a family that takes none refuses any, naming the preset."""
    params: Any = preset
    if isinstance(preset, str):
        key = preset_key(preset)
        if key not in ALL_PRESETS:
            raise UnknownPresetError(
                f"unknown preset {preset!r}; choose one of {', '.join(sorted(ALL_PRESETS))}")
        params = ALL_PRESETS[key]
    family = family_of(params)
    if family.override is not None:
        return family.override(params, **overrides)
    if overrides:
        raise InvalidParameterError(
            f"preset {params.name!r} takes no overrides (got {sorted(overrides)}); its "
            "parameters are the network's and OpenCV's")
    return params


def request_params(preset: str, overrides: Mapping[str, Any]) -> tuple[str, Any]:
    """A remote request's preset name (as registered) and parameters, checked as the service
    checks a start: a known preset, no parameter that names a file on the host, every
    override known and of the right type and range. Raises :class:`UnknownPresetError` for
    an unknown preset only, :class:`InvalidParameterError` for anything wrong with the
    overrides."""
    key = preset_key(preset)
    if key not in ALL_PRESETS:
        raise UnknownPresetError(
            f"unknown preset {preset!r}; choose one of {', '.join(sorted(ALL_PRESETS))}")
    host_only = sorted(set(overrides) & HOST_PARAMETERS)
    if host_only:
        raise InvalidParameterError(f"{', '.join(host_only)} names a file on the service's "
                                    "host; a request cannot set it")
    try:
        return key, preset_params(key, **dict(overrides))
    except InvalidParameterError:
        raise
    except UnknownPresetError as exc:  # an unknown parameter: the preset itself is known
        raise InvalidParameterError(str(exc)) from None


def available_presets(models_dir: str | Path | None = None) -> dict[str, str]:
    """Every preset, and why it cannot run here ("" when it can): a Siamese network's files
    missing or altered under ``models_dir`` (:func:`arcf.models.model_paths`)."""
    from .models import ModelNotFoundError, model_paths

    out: dict[str, str] = {}
    checked: dict[str, str] = {}
    for name, p in ALL_PRESETS.items():
        network = getattr(p, "network", None)
        if network is None:
            out[name] = ""
            continue
        if network not in checked:
            try:
                model_paths(network, models_dir)
                checked[network] = ""
            except ModelNotFoundError as exc:
                checked[network] = str(exc)
        out[name] = checked[network]
    return out


def create_tracker(
    preset: str | Params = "arcf-hc",
    *,
    colornames_path: str | Path | None = None,
    models_dir: str | Path | None = None,
    **overrides: Any,
) -> Tracker:
    """A tracker for any preset: ARCF's (``"arcf-h"``, ``"arcf-hc"``, ``"bacf"``, with keyword
    overrides), the Siamese ``"nanotrack"`` and ``"vittrack"`` (:mod:`arcf.siamese`) or the
    hybrid ``"arcf-nano"`` (:mod:`arcf.hybrid`). ``models_dir`` names the networks' folder
    (default :func:`arcf.models.models_root`), ``colornames_path`` the colour-names table.

    >>> tracker = create_tracker("arcf-h", aberrance="release")  # doctest: +SKIP
    """
    params = preset_params(preset, **overrides)
    cls = family_of(params).tracker_class()
    tracker: Tracker = cls(params, models_dir=models_dir, colornames_path=colornames_path)
    return tracker
