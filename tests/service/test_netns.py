"""The fleet over real links: three hosts as network namespaces, each with its Zenoh router
(joined as a mesh) and one service instance, a station in a fourth, and host 1's link made
slow and lossy, then cut (a partition), then restored (:mod:`arcf.loadtools.netfleet`).

What must hold: the fleet serves in every phase, the station relinks to another router during
the partition and its streams are answered there, and once the partition has healed each
instance runs its own streams' sessions again and no frame is answered twice (no split brain
left over). The figures per phase (silences, relink time) are
``benchmarks/netns_fleet.py``'s, not this test's.
"""

from __future__ import annotations

import pytest

pytest.importorskip("zenoh")

from arcf.data import data_root
from arcf.loadtools import netfleet
from arcf.loadtools.netlab import unavailable

WHY_NOT = unavailable()

pytestmark = [pytest.mark.integration, pytest.mark.heavy,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data"),
              pytest.mark.skipif(WHY_NOT is not None, reason=f"no network lab: {WHY_NOT}")]


def test_a_partition_heals_with_one_owner_per_stream() -> None:
    # each phase long enough for the partition's lease (3 s) and the station's relink
    # (1 s per router that does not answer) several times over
    report = netfleet.run(phase_s=12.0, fps=5.0)
    phases = {p["phase"]: p for p in report["phases"]}
    for name in ("clean", "slow", "restored"):
        p = phases[name]
        assert p["answered"] * 2 >= p["sent"] > 0, p  # served, frames lost on the way aside
    cut = phases["cut"]
    assert cut["station_relinked_after_s"] is not None, cut  # to host 2 or 3's router
    assert cut["answered"] > 0, cut  # the station's streams answered beyond the partition
    # healed: each instance runs its own two streams' sessions, and nothing more
    assert report["sessions_when_settled"] == dict.fromkeys(netfleet.HOSTS, 2.0), report
    assert report["answered_twice_after_settling"] == 0, report
