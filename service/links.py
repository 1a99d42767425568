"""The instance's own links to Zenoh routers, for a fleet whose routers form a mesh.

A client-mode instance is linked to one router of its ``--connect`` list. When that router
dies or is cut off, Zenoh links the session to another endpoint of the list by itself (the
instance's sessions survive it, and the cluster sorts out ownership meanwhile); this only
makes that visible: ``arcf_zenoh_routers`` (routers linked now; 0: cut off from the fleet)
and ``arcf_router_reconnects_total`` (links made again after one was lost), with a log line
each way. Polled from the main loop: the binding offers no event for a link's change.
"""

from __future__ import annotations

import logging
from typing import Any

log = logging.getLogger(__name__)


class RouterLinks:
    """Follows ``session``'s routers; ``metrics``: :mod:`arcf.service.metrics`."""

    def __init__(self, session: Any, metrics: Any) -> None:
        self.session = session
        self.metrics = metrics
        self.linked: set[str] = set()
        #: a link existed once: a new one from now on is a reconnect, not the first link
        self.had_link = False
        self.poll()

    def poll(self) -> None:
        """Compare the routers linked now with the last poll's; count what changed."""
        try:
            now = {str(z) for z in self.session.info.routers_zid()}
        except Exception:  # a closing session: nothing to follow
            return
        lost, gained = self.linked - now, now - self.linked
        if lost:
            log.warning("lost the link to router(s) %s; linked now: %s", sorted(lost),
                        sorted(now) or "none")
        if gained and self.had_link:
            self.metrics.ROUTER_RECONNECTS.inc(len(gained))
            log.warning("linked again, to router(s) %s", sorted(gained))
        self.had_link = self.had_link or bool(now)
        self.linked = now
        self.metrics.ROUTERS.set(len(now))
