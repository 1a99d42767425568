"""Hosts as Linux network namespaces on one machine, for tests over real network links.

Each host is a namespace with one interface (``eth0``, an address of a private /24) plugged
into a bridge that lives in a namespace of its own (the switch); this namespace gets a port
on the bridge too (address ``.254``), so that tests and benchmarks here read the hosts'
metrics. Nothing is routed out of the lab: its addresses exist only on these interfaces.

Faults, per host and reversible: :meth:`NetLab.cut` takes the host's port on the switch down
(a partition: its packets go nowhere, its TCP connections hang until a lease ends them) and
:meth:`NetLab.restore` brings it back; :meth:`NetLab.lose` drops a share of the packets in
and out of the host at random (iptables' ``statistic`` match: the kernel's, real loss that
TCP retransmits). Delay needs ``sch_netem``, which some kernels lack: see
:mod:`arcf.loadtools.relay` for the user-space alternative.

Needs root and iproute2 (``ip netns``); :func:`unavailable` says why it cannot run.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Sequence


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=30)


def unavailable() -> str | None:
    """Why a lab cannot be built here (None: it can)."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    for tool in ("ip", "iptables"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed"
    probe = f"arcfprobe{os.getpid()}"
    try:
        _ip("netns", "add", probe)
        _ip("netns", "del", probe)
    except (subprocess.CalledProcessError, OSError) as exc:
        return f"ip netns add fails here: {getattr(exc, 'stderr', exc)}"
    return None


class NetLab:
    """Namespaces ``hosts`` on one bridge; ``address[host]`` is each one's IPv4 address."""

    def __init__(self, hosts: Sequence[str], tag: str | None = None) -> None:
        self.tag = tag or f"a{os.getpid() % 100000}"
        # a /24 per lab, so that labs of concurrent runs do not clash on this namespace's port
        self.subnet = f"10.213.{20 + os.getpid() % 200}"
        self.hosts = list(hosts)
        self.address = {h: f"{self.subnet}.{i + 1}" for i, h in enumerate(self.hosts)}
        self.manager = f"{self.subnet}.254"
        self.switch = f"{self.tag}-sw"
        self._made: list[str] = []
        self._manager_link = f"{self.tag}m"
        try:
            self._build()
        except BaseException:
            self.close()
            raise

    def ns(self, host: str) -> str:
        """The namespace of ``host``."""
        return f"{self.tag}-{host}"

    def prefix(self, host: str) -> list[str]:
        """The command prefix that runs a program on ``host``."""
        return ["ip", "netns", "exec", self.ns(host)]

    def _port(self, host: str) -> str:
        return f"{self.tag}p{self.hosts.index(host)}"  # the switch's side (≤ 15 characters)

    def _build(self) -> None:
        _ip("netns", "add", self.switch)
        self._made.append(self.switch)
        _ip("-n", self.switch, "link", "add", "br0", "type", "bridge")
        _ip("-n", self.switch, "link", "set", "br0", "up")
        for host in self.hosts:
            ns, port = self.ns(host), self._port(host)
            inner = f"{self.tag}h{self.hosts.index(host)}"
            _ip("netns", "add", ns)
            self._made.append(ns)
            _ip("link", "add", inner, "type", "veth", "peer", "name", port)
            _ip("link", "set", inner, "netns", ns)
            _ip("link", "set", port, "netns", self.switch)
            _ip("-n", self.switch, "link", "set", port, "master", "br0")
            _ip("-n", self.switch, "link", "set", port, "up")
            _ip("-n", ns, "link", "set", inner, "name", "eth0")
            _ip("-n", ns, "addr", "add", f"{self.address[host]}/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("-n", ns, "link", "set", "lo", "up")
        # this namespace's own port, for reading metrics
        port = f"{self.tag}q"
        _ip("link", "add", self._manager_link, "type", "veth", "peer", "name", port)
        _ip("link", "set", port, "netns", self.switch)
        _ip("-n", self.switch, "link", "set", port, "master", "br0")
        _ip("-n", self.switch, "link", "set", port, "up")
        _ip("addr", "add", f"{self.manager}/24", "dev", self._manager_link)
        _ip("link", "set", self._manager_link, "up")

    # ------------------------------------------------------------------ faults
    def cut(self, host: str) -> None:
        """Partition ``host``: its port on the switch goes down."""
        _ip("-n", self.switch, "link", "set", self._port(host), "down")

    def restore(self, host: str) -> None:
        _ip("-n", self.switch, "link", "set", self._port(host), "up")

    def lose(self, host: str, probability: float) -> None:
        """Drop packets in and out of ``host``'s ``eth0`` at random with ``probability``
        (each way); 0: none."""
        for chain in ("INPUT", "OUTPUT"):
            subprocess.run([*self.prefix(host), "iptables", "-F", chain], check=True,
                           capture_output=True, timeout=30)
            if probability > 0:
                side = "-i" if chain == "INPUT" else "-o"
                subprocess.run([*self.prefix(host), "iptables", "-A", chain, side, "eth0",
                                "-m", "statistic", "--mode", "random", "--probability",
                                f"{probability:g}", "-j", "DROP"],
                               check=True, capture_output=True, timeout=30)

    def close(self) -> None:
        """Every namespace and link made (what runs in a namespace must be stopped first)."""
        subprocess.run(["ip", "link", "del", self._manager_link], capture_output=True,
                       timeout=30)
        for ns in reversed(self._made):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)
        self._made.clear()

    def __enter__(self) -> NetLab:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
