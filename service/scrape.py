"""Reading a service's Prometheus endpoint: the one parser used by the health check, the
process harness and the load tools.

The text is parsed by ``prometheus_client``'s own parser (the library that writes it), not by
pattern matching, so label values with spaces or braces, exemplars and comments cannot
mislead a reader.
"""

from __future__ import annotations

import urllib.request
from collections import defaultdict

from prometheus_client.parser import text_string_to_metric_families


def fetch(url: str, timeout: float = 5.0) -> str:
    """The exposition text at ``url`` (raises ``OSError`` when it cannot be read)."""
    with urllib.request.urlopen(url, timeout=timeout) as response:
        return response.read().decode()


def series(text: str) -> dict[str, list[tuple[dict[str, str], float]]]:
    """Every sample by its name (``arcf_errors_total``, ``arcf_decode_seconds_count``, ...):
    a list of (labels, value), one per series."""
    out: dict[str, list[tuple[dict[str, str], float]]] = defaultdict(list)
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            out[sample.name].append((dict(sample.labels), float(sample.value)))
    return dict(out)


def totals(text: str) -> dict[str, float]:
    """Each sample name's value summed over its label values (a counter's total)."""
    return {name: sum(v for _, v in values) for name, values in series(text).items()}


def by_label(text: str, name: str, label: str) -> dict[str, float]:
    """One metric's value per value of one label, e.g. ``arcf_errors_total`` by ``kind``."""
    out: dict[str, float] = defaultdict(float)
    for labels, value in series(text).get(name, []):
        out[labels.get(label, "")] += value
    return dict(out)


def scrape(url: str | None, timeout: float = 5.0) -> dict[str, float]:
    """``totals`` of the endpoint at ``url``; ``{}`` when there is no URL."""
    return totals(fetch(url, timeout)) if url else {}


def delta(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    """How much each counter moved between two :func:`scrape` readings (histogram buckets and
    creation times left out; their counts and sums are kept)."""
    return {k: after.get(k, 0.0) - before.get(k, 0.0) for k in after
            if not k.endswith(("_bucket", "_created"))}
