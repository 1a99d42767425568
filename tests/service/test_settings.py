"""Service settings declared once: flags, variables and the config file come from the fields."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import pytest

from arcf.service.app import build_parser
from arcf.service.health import main as health_main
from arcf.service.settings import ServiceSettings, add_arguments, from_arguments


def parse(argv: list[str], env: dict[str, str] | None = None) -> ServiceSettings:
    return from_arguments(build_parser().parse_args(argv), env=env or {})


def test_every_setting_has_a_flag_a_variable_and_help() -> None:
    ap = argparse.ArgumentParser()
    add_arguments(ap)
    flags = {a.dest for a in ap._actions}
    for f in dataclasses.fields(ServiceSettings):
        assert f.name in flags, f.name
        assert f.metadata.get("help"), f"{f.name} has no help"
        value = getattr(ServiceSettings(), f.name)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            env = {"ARCF_SERVICE_" + f.name.upper(): str(value)}
            assert getattr(ServiceSettings.from_env(env), f.name) == value


def test_config_file_then_variables_then_flags(tmp_path: Path) -> None:
    config = tmp_path / "arcf.toml"
    config.write_text('max_stream_fps = 12.5\nframe_queue = 3\nconnect = ["tcp/10.0.0.1:7447"]\n'
                      'mode = "client"\nlease_ms = 2500\n')
    s = parse(["--settings", str(config)])
    assert (s.max_stream_fps, s.frame_queue, s.connect, s.mode, s.lease_ms) == (
        12.5, 3, ("tcp/10.0.0.1:7447",), "client", 2500)
    s = parse(["--settings", str(config)], env={"ARCF_SERVICE_FRAME_QUEUE": "4",
                                               "ARCF_SERVICE_CONNECT": "tcp/a:1, tcp/b:2"})
    assert s.frame_queue == 4 and s.connect == ("tcp/a:1", "tcp/b:2")
    s = parse(["--settings", str(config), "--frame-queue", "5", "--connect", "tcp/c:3",
               "--connect", "tcp/d:4", "--worker-start-s", "30"],
              env={"ARCF_SERVICE_FRAME_QUEUE": "4"})
    assert (s.frame_queue, s.connect, s.worker_start_s, s.max_stream_fps) == (
        5, ("tcp/c:3", "tcp/d:4"), 30.0, 12.5)


@pytest.mark.parametrize(("text", "words"), [
    ("max_stream_fsp = 3\n", "unknown settings ['max_stream_fsp']"),
    ('frame_queue = "many"\n', "setting frame_queue"),
    ("frame_queue = true\n", "setting frame_queue"),
    ("frame_queue = [\n", "config file"),
    ("frame_queue = 0\n", "frame_queue must be >= 1"),
])
def test_a_bad_config_file_is_refused_with_the_reason(tmp_path: Path, text: str,
                                                       words: str) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(text)
    with pytest.raises(ValueError, match=words.replace("[", r"\[").replace("]", r"\]")):
        parse(["--settings", str(config)])
    with pytest.raises(ValueError, match="config file"):
        parse(["--settings", str(tmp_path / "missing.toml")])


def test_stale_after_s_is_off_or_above_a_frame_interval() -> None:
    assert ServiceSettings().stale_after_s == 0.8  # room to say so within 1 s
    assert parse(["--stale-after-s", "0"]).stale_after_s == 0  # off
    assert parse(["--stale-after-s", "0.25"]).stale_after_s == 0.25
    for bad in ("0.05", "-1", "nan", "inf"):
        with pytest.raises(ValueError, match="stale_after_s must be 0"):
            parse(["--stale-after-s", bad])


def test_a_bad_variable_is_refused() -> None:
    with pytest.raises(ValueError, match="setting max_pixels"):
        ServiceSettings.from_env({"ARCF_SERVICE_MAX_PIXELS": "lots"})


def test_health_check_reads_the_services_variables(monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """The probe looks where the service would listen: its metrics port from the same
    variable (here a closed port), and a malformed variable is reported, not a traceback."""
    monkeypatch.setenv("ARCF_SERVICE_METRICS_PORT", "9")
    assert health_main() == 1
    assert "127.0.0.1:9/metrics" in capsys.readouterr().out
    monkeypatch.setenv("ARCF_SERVICE_METRICS_PORT", "nine")
    assert health_main() == 1
    assert "setting metrics_port" in capsys.readouterr().out


def test_zenoh_flags_follow_the_zenoh_python_examples(tmp_path: Path) -> None:
    """``-m -e -l -c`` as in zenoh-python's examples, for the service and the router alike."""
    config = tmp_path / "zenoh.json5"
    config.write_text("{}")
    s = parse(["-m", "client", "-e", "tcp/10.0.0.2:7447", "-e", "tcp/10.0.0.3:7447",
               "-l", "tcp/127.0.0.1:7448", "-c", str(config)])
    assert (s.mode, s.connect, s.listen, s.zenoh_config) == (
        "client", ("tcp/10.0.0.2:7447", "tcp/10.0.0.3:7447"), ("tcp/127.0.0.1:7448",), config)
    from arcf.service.router import main as router_main

    with pytest.raises(SystemExit) as info:  # parsed, then refused: a mode is not a router's
        router_main(["-m", "peer"])
    assert info.value.code == 2
