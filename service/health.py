"""``arcf-healthcheck``: exit 0 when the local service instance is healthy (container probe).

Healthy means its metrics endpoint answers, the instance is ready (it served a start of its
own through its control key: ``arcf_ready`` 1) and reports at least one live worker. It reads the
port and host as the service reads its ``ARCF_SERVICE_*`` variables (``ServiceSettings``), so
the probe needs no arguments inside the image.
"""

from __future__ import annotations

import sys

from .scrape import fetch, series
from .settings import ServiceSettings


def check(url: str, timeout: float = 3.0) -> tuple[bool, str]:
    try:
        text = fetch(url, timeout)
    except OSError as exc:
        return False, f"metrics endpoint {url} unreachable: {exc}"
    try:
        found = series(text)
    except ValueError as exc:  # not Prometheus text
        return False, f"metrics endpoint {url} answered something else: {exc}"
    workers = len(found.get("arcf_worker_busy_ratio", []))
    if not any(value == 1 for _, value in found.get("arcf_ready", [])):
        return False, "not ready: no start served yet"
    if workers == 0:
        return False, "no live worker reported"
    return True, f"ok: {workers} workers"


def main() -> int:
    try:  # the service's own settings: its config file is not known here, its variables are
        settings = ServiceSettings.from_env()
    except ValueError as exc:
        print(f"unhealthy: {exc}")
        return 1
    host = settings.metrics_host
    if host in ("0.0.0.0", "::", ""):
        host = "127.0.0.1"
    ok, message = check(f"http://{host}:{settings.metrics_port}/metrics")
    print(message)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
