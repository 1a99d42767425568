"""The compose stack of ``deploy/`` as the container tests and benchmarks drive it: built as an
air-gapped site builds it (``compose.yaml`` + ``compose.local.yaml``), every published port on
127.0.0.1, torn down with nothing left behind."""

from __future__ import annotations

import json
import subprocess
import time
import urllib.parse
import urllib.request
from collections.abc import Mapping
from pathlib import Path
from typing import Any

#: the service instances of deploy/compose.yaml
INSTANCES = ("arcf-1", "arcf-2")


def stack_env(base: Mapping[str, str], *, router_port: int, prometheus_port: int, data: Path,
              version: str, workers_per_instance: int = 1, lease_ms: int = 3000
              ) -> dict[str, str]:
    """The compose file's variables for a stack published on loopback."""
    return {**base, "ARCF_PUBLISH_ADDRESS": "127.0.0.1", "ARCF_ROUTER_PORT": str(router_port),
            "ARCF_PROMETHEUS_PORT": str(prometheus_port), "ARCF_DATA": str(data),
            "ARCF_WORKERS_PER_INSTANCE": str(workers_per_instance), "ARCF_VERSION": version,
            "ARCF_LEASE_MS": str(lease_ms)}


class ComposeStack:
    """One compose project of the stack in ``deploy``."""

    def __init__(self, project: str, env: Mapping[str, str], deploy: Path,
                 prometheus_port: int | None = None) -> None:
        self.project, self.env, self.deploy = project, dict(env), deploy
        self.prometheus_port = prometheus_port

    def __call__(self, *args: str, timeout: float = 600) -> str:
        """``docker-compose <args>`` on this project; its stdout (raises with the output's
        tail when it fails)."""
        cmd = ["docker-compose", "-f", str(self.deploy / "compose.yaml"), "-f",
               str(self.deploy / "compose.local.yaml"), "-p", self.project, *args]
        out = subprocess.run(cmd, env=self.env, capture_output=True, text=True, timeout=timeout)
        if out.returncode != 0:
            raise RuntimeError(f"docker-compose {' '.join(args)}: "
                               f"{out.stdout[-3000:]}{out.stderr[-3000:]}")
        return out.stdout

    def container(self, service: str) -> str:
        return self("ps", "-q", service).strip()

    def inspect(self, service: str) -> dict[str, Any]:
        out = subprocess.run(["docker", "inspect", self.container(service)],
                             capture_output=True, text=True, check=True)
        return json.loads(out.stdout)[0]

    def health(self, service: str) -> str:
        return self.inspect(service)["State"].get("Health", {}).get("Status", "none")

    def wait_healthy(self, services: tuple[str, ...] = INSTANCES,
                     timeout: float = 300) -> float:
        """Seconds until every service's own HEALTHCHECK says healthy (raises on timeout).
        The deadline is far above an idle start (about 20 s): two instances warming their
        trackers' kernels side by side on a 2-core machine that other work keeps busy took
        over 120 s."""
        t0 = time.monotonic()
        status = dict.fromkeys(services, "")
        while time.monotonic() - t0 < timeout:
            status = {s: self.health(s) for s in services}
            if all(v == "healthy" for v in status.values()):
                return time.monotonic() - t0
            time.sleep(1.0)
        raise TimeoutError(f"not healthy within {timeout:.0f} s: {status}")

    def prometheus(self, path: str, **query: str) -> Any:
        """The ``data`` of a Prometheus HTTP API answer."""
        url = f"http://127.0.0.1:{self.prometheus_port}{path}"
        if query:
            url += "?" + urllib.parse.urlencode(query)
        with urllib.request.urlopen(url, timeout=5) as response:
            body = json.load(response)
        if body["status"] != "success":
            raise RuntimeError(f"Prometheus {path}: {body}")
        return body["data"]

    def leftovers(self) -> dict[str, list[str]]:
        """Containers, networks and volumes of this project still there."""
        label = f"label=com.docker.compose.project={self.project}"
        found = {}
        for kind, cmd in (("containers", ["docker", "ps", "-aq"]),
                          ("networks", ["docker", "network", "ls", "-q"]),
                          ("volumes", ["docker", "volume", "ls", "-q"])):
            out = subprocess.run([*cmd, "--filter", label], capture_output=True, text=True,
                                 check=True)
            found[kind] = out.stdout.split()
        return found

    def down(self) -> None:
        """Everything of the project removed (errors ignored: this is the cleanup path)."""
        subprocess.run(["docker-compose", "-f", str(self.deploy / "compose.yaml"), "-f",
                        str(self.deploy / "compose.local.yaml"), "-p", self.project, "down",
                        "-v", "--remove-orphans"], env=self.env, capture_output=True,
                       timeout=300)
