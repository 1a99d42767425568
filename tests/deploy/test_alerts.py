"""The fleet's alert rules (deploy/prometheus/alerts.yml): every metric they read is one the
service or arcf-router exports, Prometheus's own checker accepts them, and their unit tests
(alerts.test.yml: series in, alerts out, with promtool) pass: each alert fires on what it
names and stays quiet otherwise."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
PROMETHEUS = ROOT / "deploy" / "prometheus"

needs_promtool = pytest.mark.skipif(shutil.which("promtool") is None,
                                    reason="promtool (Debian's prometheus package) not installed")


def exported() -> set[str]:
    """The metric names the service (service/metrics.py) and arcf-router export."""
    names = set(re.findall(r'"(arcf_[a-z_]+)"', (ROOT / "service" / "metrics.py").read_text()))
    names |= set(re.findall(r'"(arcf_router[a-z_]*)"', (ROOT / "service" / "router.py")
                            .read_text()))
    return names


def rules() -> list[dict[str, object]]:
    doc = yaml.safe_load((PROMETHEUS / "alerts.yml").read_text())
    return [rule for group in doc["groups"] for rule in group["rules"]]


def test_alerts_read_exported_metrics() -> None:
    names = exported()
    for rule in rules():
        for metric in re.findall(r"\barcf_[a-z_]+", str(rule["expr"])):
            base = re.sub(r"_(bucket|sum|count)$", "", metric)
            assert base in names, f"{rule['alert']}: {metric} is not exported"


def test_every_alert_is_unit_tested() -> None:
    tests = yaml.safe_load((PROMETHEUS / "alerts.test.yml").read_text())
    fired = {case["alertname"] for test in tests["tests"] for case in test["alert_rule_test"]
             if case["exp_alerts"]}
    assert fired == {str(rule["alert"]) for rule in rules()}


def test_prometheus_loads_the_rules() -> None:
    config = yaml.safe_load((PROMETHEUS / "prometheus.yml").read_text())
    assert config["rule_files"] == ["alerts.yml"]


@needs_promtool
def test_promtool_checks_the_rules() -> None:
    out = subprocess.run(["promtool", "check", "rules", "alerts.yml"], cwd=PROMETHEUS,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"{len(rules())} rules found" in out.stdout


@needs_promtool
def test_the_alerts_unit_tests_pass() -> None:
    out = subprocess.run(["promtool", "test", "rules", "alerts.test.yml"], cwd=PROMETHEUS,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
