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
:mod:`arcf.service` (tests/test_layers.py).
"""

from __future__ import annotations

from .sdk import MessageStream, ServiceError, TrackingClient

__all__ = ["MessageStream", "ServiceError", "TrackingClient"]
