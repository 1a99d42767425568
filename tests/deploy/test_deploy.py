"""The deployment files, checked as far as a machine without a Docker engine allows.

* compose: parsed and cross-checked (images, mounts that exist, settings the service knows,
  Prometheus targets), and ``docker compose config`` when a compose binary is installed;
* Prometheus: parsed, targets match the compose services, ``promtool check config`` if present;
* Grafana: provisioning parsed, dashboard JSON valid, every query names a metric we export;
* Zenoh: every config file parsed by Zenoh itself (it rejects unknown keys), and the router
  config run as a real router that a client and the service reach;
* Dockerfile: its structure (the images are built and run by tests/deploy/test_containers.py where a
  Docker engine answers).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from arcf.loadtools.procs import free_port
from arcf.service.settings import ServiceSettings

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"


def compose() -> dict[str, Any]:
    return yaml.safe_load((DEPLOY / "compose.yaml").read_text())


def arcf_services(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {name: svc for name, svc in doc["services"].items()
            if svc.get("build", {}).get("dockerfile") == "deploy/Dockerfile"}


def exported_metrics() -> set[str]:
    """The service's metrics and arcf-router's."""
    text = (ROOT / "service" / "metrics.py").read_text()
    router = (ROOT / "service" / "router.py").read_text()
    return (set(re.findall(r'"(arcf_[a-z_]+)"', text))
            | set(re.findall(r'"(arcf_router[a-z_]*)"', router)))


# ---------------------------------------------------------------------------------- compose
def test_compose_stack_has_router_instances_prometheus_grafana() -> None:
    doc = compose()
    services = doc["services"]
    assert services["zenoh-router"]["image"].startswith("eclipse/zenoh:")
    instances = arcf_services(doc)
    assert len(instances) >= 2
    fields = set(ServiceSettings.__dataclass_fields__)
    ids = set()
    for svc in instances.values():
        env = svc["environment"]
        for key in env:
            if key.startswith("ARCF_SERVICE_"):  # every setting is one the service reads
                assert key.removeprefix("ARCF_SERVICE_").lower() in fields, key
        assert env["ARCF_SERVICE_MODE"] == "client"
        assert env["ARCF_SERVICE_CONNECT"] == "tcp/zenoh-router:7447"
        ids.add(env["ARCF_SERVICE_INSTANCE_ID"])
        assert "shm_size" in svc  # sized explicitly for containers
        assert svc["depends_on"]["zenoh-router"]
    assert len(ids) == len(instances)  # distinct instance ids
    assert "prometheus" in services and "grafana" in services
    # every file mounted from the repository exists
    for svc in services.values():
        for volume in svc.get("volumes", []):
            source = volume.split(":")[0]
            if source.startswith("./"):
                assert (DEPLOY / source).exists(), source


@pytest.mark.integration
def test_compose_config_validates_with_docker_compose() -> None:
    if shutil.which("docker") and subprocess.run(["docker", "compose", "version"],
                                                 capture_output=True).returncode == 0:
        cmd = ["docker", "compose"]
    elif shutil.which("docker-compose"):
        cmd = ["docker-compose"]
    else:
        pytest.skip("no docker compose binary on this machine")
    out = subprocess.run([*cmd, "-f", str(DEPLOY / "compose.yaml"), "config"],
                         capture_output=True, text=True, cwd=DEPLOY, timeout=60)
    assert out.returncode == 0, out.stderr
    resolved = yaml.safe_load(out.stdout)
    assert resolved["services"]["arcf-1"]["environment"]["ARCF_SERVICE_INSTANCE_ID"] == "arcf-1"


# ---------------------------------------------------------------------------------- prometheus
def test_prometheus_scrapes_every_instance() -> None:
    prom = yaml.safe_load((DEPLOY / "prometheus" / "prometheus.yml").read_text())
    jobs = {job["job_name"]: job for job in prom["scrape_configs"]}
    targets = {t for sc in jobs["arcf-service"]["static_configs"] for t in sc["targets"]}
    doc = compose()
    for name, svc in arcf_services(doc).items():
        port = svc["environment"].get("ARCF_SERVICE_METRICS_PORT") or \
            doc["x-arcf-env"]["ARCF_SERVICE_METRICS_PORT"]
        assert f"{name}:{port}" in targets
    if shutil.which("promtool"):
        out = subprocess.run(["promtool", "check", "config",
                              str(DEPLOY / "prometheus" / "prometheus.yml")],
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stdout + out.stderr


# ---------------------------------------------------------------------------------- grafana
def test_grafana_dashboard_queries_exported_metrics() -> None:
    ds = yaml.safe_load((DEPLOY / "grafana/provisioning/datasources/prometheus.yaml").read_text())
    uid = ds["datasources"][0]["uid"]
    prov = yaml.safe_load((DEPLOY / "grafana/provisioning/dashboards/arcf.yaml").read_text())
    assert prov["providers"][0]["options"]["path"] == "/var/lib/grafana/dashboards"
    dash = json.loads((DEPLOY / "grafana/dashboards/arcf.json").read_text())
    names = exported_metrics()
    titles = " ".join(p["title"].lower() for p in dash["panels"])
    for needed in ("latency", "fps", "sessions", "dropped", "errors"):
        assert needed in titles
    ids = [p["id"] for p in dash["panels"]]
    assert len(ids) == len(set(ids))
    for panel in dash["panels"]:
        assert panel["datasource"]["uid"] == uid
        for target in panel["targets"]:
            for metric in re.findall(r"\barcf_[a-z_]+", target["expr"]):
                base = re.sub(r"_(bucket|sum|count)$", "", metric)
                assert base in names, f"{panel['title']}: {metric} is not exported"


# ---------------------------------------------------------------------------------- zenoh
@pytest.mark.parametrize("name", ["router", "service", "router-tls-acl", "client-tls"])
def test_zenoh_configs_parse(name: str) -> None:
    zenoh = pytest.importorskip("zenoh")
    zenoh.Config.from_file(str(DEPLOY / "zenoh" / f"{name}.json5"))  # strict: unknown keys fail


@pytest.mark.integration
def test_router_config_runs_a_router_the_service_reaches() -> None:
    zenoh = pytest.importorskip("zenoh")
    port = free_port()
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh" / "router.json5"))
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("plugins", "{}")  # no REST port in a test
    with zenoh.open(conf):
        from arcf.client import TrackingClient
        from arcf.loadtools.procs import ServiceProcess

        svc = ServiceProcess("--zenoh-config", str(DEPLOY / "zenoh" / "service.json5"),
                             connect=f"tcp/127.0.0.1:{port}", workers=1)
        try:
            with TrackingClient(connect=[f"tcp/127.0.0.1:{port}"]) as client:
                assert client.status().workers == 1
        finally:
            assert svc.stop() == 0


# ---------------------------------------------------------------------------------- Dockerfile
def dockerfile_stages() -> list[dict[str, Any]]:
    """The Dockerfile as stages of (instruction, argument) pairs, continuations joined (comment
    lines dropped first, as Docker does, also inside a continued instruction)."""
    text = (DEPLOY / "Dockerfile").read_text()
    text = re.sub(r"^\s*#.*\n", "", text, flags=re.M)
    text = re.sub(r"\\\n\s*", " ", text)
    stages: list[dict[str, Any]] = []
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        op, _, arg = line.partition(" ")
        op = op.upper()
        if op == "FROM":
            stages.append({"from": arg, "steps": []})
        elif stages:
            stages[-1]["steps"].append((op, arg.strip()))
    return stages


def test_dockerfile_is_multistage_slim_nonroot_with_healthcheck() -> None:
    """Static checks; tests/deploy/test_containers.py builds and runs the image for real."""
    text = (DEPLOY / "Dockerfile").read_text()
    base = re.search(r"^ARG BASE_IMAGE=(\S+)", text, flags=re.M)
    assert base and "slim" in base.group(1)  # the official slim image unless told otherwise
    stages = dockerfile_stages()
    assert len(stages) >= 2
    build, runtime = stages[0], stages[-1]
    # the build stage compiles (the partial JPEG decoder); what runs is the slim base
    assert build["from"].startswith("${BUILD_IMAGE}")
    assert runtime["from"].startswith("${BASE_IMAGE}")
    install = " ".join(arg for op, arg in build["steps"] if op == "RUN")
    assert "PIP_NO_INDEX=1" in install and "PIP_FIND_LINKS=/wheelhouse" in install  # offline
    ops = dict(runtime["steps"])
    user = ops["USER"].split(":")[0]
    assert user.isdigit() and int(user) != 0  # numeric, so runAsNonRoot can verify it
    assert "HEALTHCHECK" in ops and "arcf-healthcheck" in ops["HEALTHCHECK"]
    assert json.loads(ops["ENTRYPOINT"]) == ["arcf-service"]
    copies = [arg for op, arg in runtime["steps"] if op == "COPY"]
    # only what the build stage made: the virtualenv and the checked network files
    assert copies and all("--from=build" in c for c in copies)
    assert "ARCF_MODELS=/opt/arcf-models" in ops["ENV"].split()
    assert any(c.split()[-1] == "/opt/arcf-models" for c in copies)
    assert "arcf models --dir /opt/arcf-models" in install  # the build checks each file


def _load_offline() -> Any:
    """deploy/offline.py as a module (a script, not part of the package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("offline", DEPLOY / "offline.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_offline_fills_the_models_folder_the_image_copies(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """deploy/offline.py's models step copies the network folders as published (the build
    context lets deploy/models through, and git keeps it empty)."""
    src = tmp_path / "models"
    (src / "vittrack").mkdir(parents=True)
    (src / "vittrack" / "net.onnx").write_bytes(b"onnx")
    (src / "README.md").write_text("not copied")
    dest = tmp_path / "dest"
    (dest / "gone").mkdir(parents=True)
    (dest / "gone" / "old.onnx").write_bytes(b"no longer in the source")
    offline = _load_offline()
    offline.copy_models(src, dest)
    assert sorted(p.relative_to(dest).as_posix() for p in dest.rglob("*")) == [
        "vittrack", "vittrack/net.onnx"]
    (dest / "vittrack" / "net.onnx").write_bytes(b"ONNX")  # same size, other bytes: replaced
    offline.copy_models(src, dest)
    assert (dest / "vittrack" / "net.onnx").read_bytes() == b"onnx"
    # by default from where the package finds them: $ARCF_MODELS, else beside the data root
    monkeypatch.delenv("ARCF_MODELS", raising=False)
    monkeypatch.setenv("ARCF_DATA", str(tmp_path / "data"))
    assert offline.models_source() == tmp_path / "models"
    monkeypatch.setenv("ARCF_MODELS", str(src))
    assert offline.models_source() == src
    ignore = (DEPLOY.parent / ".dockerignore").read_text().split()
    assert ignore.index("!deploy/models") > ignore.index("deploy/*")
    assert (DEPLOY / "models" / ".gitignore").read_text().split()[-2:] == ["*", "!.gitignore"]


def test_local_override_builds_everything_and_keeps_the_stack() -> None:
    """compose.local.yaml (no registries): every image built from the local base, the router
    from our image, Grafana behind a profile; resolved together with compose.yaml."""
    local = yaml.safe_load((DEPLOY / "compose.local.yaml").read_text())["services"]
    base = compose()["services"]
    assert set(local) <= set(base)
    for name, svc in local.items():
        if name == "grafana":
            assert svc["profiles"] == ["grafana"]
            continue
        assert "build" in svc, name
        assert svc["build"]["args"]["BASE_IMAGE"].startswith("${ARCF_BASE_IMAGE")
        if svc["build"].get("dockerfile") == "deploy/Dockerfile":  # compiles: the build image
            assert svc["build"]["args"]["BUILD_IMAGE"].startswith("${ARCF_BUILD_IMAGE")
    assert local["zenoh-router"]["entrypoint"] == ["arcf-router"]
    assert (DEPLOY / "prometheus" / "Dockerfile").is_file()
    if not shutil.which("docker-compose"):
        pytest.skip("no docker-compose binary on this machine")
    out = subprocess.run(["docker-compose", "-f", str(DEPLOY / "compose.yaml"), "-f",
                          str(DEPLOY / "compose.local.yaml"), "config"],
                         capture_output=True, text=True, cwd=DEPLOY, timeout=60,
                         env={**os.environ, "ARCF_PUBLISH_ADDRESS": "127.0.0.1"})
    assert out.returncode == 0, out.stderr
    resolved = yaml.safe_load(out.stdout)["services"]
    assert resolved["arcf-1"]["read_only"] is True
    port = resolved["zenoh-router"]["ports"][0]  # "ip:host:container" (v1) or a mapping (v2)
    assert (port["host_ip"] if isinstance(port, dict) else port.split(":")[0]) == "127.0.0.1"


def test_the_image_copies_every_folder_the_package_is_built_from() -> None:
    """The Dockerfile copies the sources folder by folder: each folder pyproject maps into the
    ``arcf`` package must be among them, or the image's ``pip install`` fails."""
    import tomllib

    root = DEPLOY.parent
    folders = set(tomllib.loads((root / "pyproject.toml").read_text())
                  ["tool"]["setuptools"]["package-dir"].values())
    copied = {line.split()[1] for line in (DEPLOY / "Dockerfile").read_text().splitlines()
              if line.startswith("COPY ") and "--from" not in line}
    assert folders <= copied, sorted(folders - copied)
