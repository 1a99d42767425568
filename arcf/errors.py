"""Errors the library raises on bad input.

All of them derive from :class:`ValueError` so that callers that only know "bad argument" can
catch them generically, while a service can tell a bad box from a bad frame.
"""

from __future__ import annotations


class ARCFError(ValueError):
    """Base class of every input error the tracker library raises."""


class InvalidBoxError(ARCFError):
    """The box is NaN, non-positive in size, or lies entirely outside the frame."""


class InvalidFrameError(ARCFError):
    """The frame is not a uint8 HxW or HxWx3 array (or changed size mid-sequence)."""


class UnknownPresetError(ARCFError):
    """No preset of that name exists, or an override names an unknown parameter."""


class InvalidParameterError(UnknownPresetError):
    """An override of the wrong type or outside its declared range (``arcf.presets.TUNABLE``);
    an :class:`UnknownPresetError`, as every refused parameter set has always been."""


class NotInitializedError(RuntimeError):
    """``update`` was called before ``init``."""


class ColorNamesNotFoundError(FileNotFoundError):
    """The Color Names table (needed by ARCF-HC on colour frames) is missing."""
