"""The one reader of a service's /metrics (service/scrape.py) and the health check built on it,
against a real HTTP server on loopback."""

from __future__ import annotations

import http.server
import threading
from collections.abc import Iterator

import pytest

from arcf.service.health import check
from arcf.service.scrape import scrape, series, totals

EXPOSITION = """\
# HELP arcf_errors_total Errors by code.
# TYPE arcf_errors_total counter
arcf_errors_total{code="decode_error",detail="a } brace, a space"} 3.0
arcf_errors_total{code="stale_frame"} 2.0
# HELP arcf_decode_seconds Decode time.
# TYPE arcf_decode_seconds histogram
arcf_decode_seconds_bucket{le="0.01"} 4.0
arcf_decode_seconds_bucket{le="+Inf"} 5.0
arcf_decode_seconds_count 5.0
arcf_decode_seconds_sum 0.02
# HELP arcf_ready Served a start of its own.
# TYPE arcf_ready gauge
arcf_ready 1.0
# HELP arcf_worker_busy_ratio Busy share per worker.
# TYPE arcf_worker_busy_ratio gauge
arcf_worker_busy_ratio{worker="0"} 0.5
arcf_worker_busy_ratio{worker="1"} 0.25
"""


@pytest.fixture
def server() -> Iterator[tuple[str, dict[str, str]]]:
    page = {"text": EXPOSITION}

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # the stdlib handler's name
            body = page["text"].encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/plain; version=0.0.4")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/metrics", page
    finally:
        httpd.shutdown()
        httpd.server_close()


def test_totals_sum_over_label_values_and_keep_every_sample_name() -> None:
    got = totals(EXPOSITION)
    assert got["arcf_errors_total"] == 5.0  # a label value with '}' and spaces is no trap
    assert got["arcf_decode_seconds_count"] == 5.0
    assert got["arcf_decode_seconds_sum"] == pytest.approx(0.02)
    assert [labels["worker"] for labels, _ in series(EXPOSITION)["arcf_worker_busy_ratio"]] == [
        "0", "1"]


def test_scrape_reads_a_real_endpoint(server: tuple[str, dict[str, str]]) -> None:
    url, _ = server
    assert scrape(url)["arcf_errors_total"] == 5.0
    assert scrape(None) == {}


def test_health_check_needs_readiness_and_a_live_worker(
        server: tuple[str, dict[str, str]]) -> None:
    url, page = server
    assert check(url) == (True, "ok: 2 workers")
    page["text"] = EXPOSITION.replace("arcf_ready 1.0", "arcf_ready 0.0")
    assert check(url) == (False, "not ready: no start served yet")
    page["text"] = EXPOSITION.split("# HELP arcf_worker_busy_ratio")[0]
    ok, message = check(url)
    assert not ok and "no live worker" in message
    page["text"] = "<html>not metrics</html>\n"
    ok, message = check(url)
    assert not ok


def test_health_check_reports_an_unreachable_endpoint() -> None:
    ok, message = check("http://127.0.0.1:9/metrics", timeout=1.0)
    assert not ok and "unreachable" in message


def test_one_metric_by_one_label() -> None:
    from arcf.service.scrape import by_label

    text = ('# TYPE arcf_errors_total counter\n'
            'arcf_errors_total{kind="rate_limited",worker="0"} 3.0\n'
            'arcf_errors_total{kind="rate_limited",worker="1"} 2.0\n'
            'arcf_errors_total{kind="invalid_key",worker="0"} 1.0\n')
    assert by_label(text, "arcf_errors_total", "kind") == {"rate_limited": 5.0,
                                                            "invalid_key": 1.0}
    assert by_label(text, "arcf_frames_total", "kind") == {}
