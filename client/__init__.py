"""The client side of the service: what a ground station, an adapter and the service itself
share, and nothing of the server's internals.

- :mod:`arcf.client.sdk`: :class:`TrackingClient` (publish frames, control sessions, receive
  results), exported here;
- :mod:`arcf.client.transport`: Zenoh sessions and their command-line flags;
- :mod:`arcf.client.media`: the wire encodings (one table: header reader, decoder, region
  decoder, encoder) and video decoding;
- :mod:`arcf.client.cdr`, :mod:`arcf.client.foxglove`: ROS 2's CDR and Foxglove's
  ``CompressedVideo``.

An adapter is a client: it imports this package and :mod:`arcf.schemas`, never
:mod:`arcf.service` (tests/test_layers.py). Names load on first use, so that importing a
submodule (the media decoders, say) does not open Zenoh.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .sdk import MessageStream, ServiceError, TrackingClient

_HOME = dict.fromkeys(("MessageStream", "ServiceError", "TrackingClient"), "sdk")


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'arcf.client' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{home}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_HOME])


__all__ = ["MessageStream", "ServiceError", "TrackingClient"]
