"""``arcf-healthcheck``: exit 0 when the local service instance is healthy (container probe).

Healthy means its metrics endpoint answers and reports at least one live worker. It reads the
port and host from the same ``ARCF_SERVICE_*`` variables as the service, so the probe needs no
arguments inside the image.
"""

from __future__ import annotations

import os
import sys

from .scrape import fetch, series


def check(url: str, timeout: float = 3.0) -> tuple[bool, str]:
    try:
        text = fetch(url, timeout)
    except OSError as exc:
        return False, f"metrics endpoint {url} unreachable: {exc}"
    try:
        workers = len(series(text).get("arcf_worker_busy_ratio", []))
    except ValueError as exc:  # not Prometheus text
        return False, f"metrics endpoint {url} answered something else: {exc}"
    if workers == 0:
        return False, "no live worker reported"
    return True, f"ok: {workers} workers"


def main() -> int:
    host = os.environ.get("ARCF_SERVICE_METRICS_HOST", "127.0.0.1")
    if host in ("0.0.0.0", "::", ""):
        host = "127.0.0.1"
    port = os.environ.get("ARCF_SERVICE_METRICS_PORT", "9464")
    ok, message = check(f"http://{host}:{port}/metrics")
    print(message)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
