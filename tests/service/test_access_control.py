"""Access control on loopback: Zenoh's mutual TLS and ACL, configured from the deployment's own
example files (deploy/zenoh/router-tls-acl.json5 and client-tls.json5, with only certificate
paths and endpoints changed). An authorised ground station tracks through a real service; a
station with a valid certificate but no rights is refused both control and frame publishing;
a client without a certificate cannot connect at all."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import zenoh

from arcf.client import ServiceError, TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.video import encode_video
from arcf.loadtools.waiting import next_result, wait_for_peers, wait_until
from arcf.schemas import Status, StatusRequest, decode, encode

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy" / "zenoh"

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl"),
    pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(), reason="needs ../shared/data"),
]


def make_certs(d: Path, names: list[str]) -> None:
    """A throwaway CA and one certificate per common name (SAN localhost / 127.0.0.1)."""
    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)
    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca-key.pem", "-out",
        "ca.pem", "-days", "2", "-subj", "/CN=arcf-test-ca")
    for cn in names:
        (d / f"{cn}.ext").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n"
                                     "extendedKeyUsage=serverAuth,clientAuth\n")
        run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{cn}-key.pem", "-out",
            f"{cn}.csr", "-subj", f"/CN={cn}")
        run("x509", "-req", "-in", f"{cn}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
            "-CAcreateserial", "-out", f"{cn}.pem", "-days", "2", "-extfile", f"{cn}.ext")


def peer_config(d: Path, cn: str | None, endpoint: str) -> Path:
    """deploy/zenoh/client-tls.json5 with this peer's certificate (none: no client cert)."""
    text = (DEPLOY / "client-tls.json5").read_text()
    text = text.replace("tls/router.example.org:7447", endpoint)
    text = text.replace("/certs/ca.pem", str(d / "ca.pem"))
    if cn is None:
        text = "\n".join(line for line in text.splitlines() if "connect_" not in line)
    else:
        text = text.replace("/certs/peer.pem", str(d / f"{cn}.pem"))
        text = text.replace("/certs/peer-key.pem", str(d / f"{cn}-key.pem"))
    path = d / f"peer-{cn}.json5"
    path.write_text(text)
    return path


def router_config(d: Path) -> tuple[zenoh.Config, str]:
    """deploy/zenoh/router-tls-acl.json5 on a free loopback port with the certificates of
    ``d``, and the endpoint peers connect to."""
    port = free_port()
    conf = zenoh.Config.from_file(str(DEPLOY / "router-tls-acl.json5"))
    conf.insert_json5("listen/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    for key, name in (("root_ca_certificate", "ca.pem"), ("listen_certificate", "router.pem"),
                      ("listen_private_key", "router-key.pem")):
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(str(d / name)))
    return conf, f"tls/localhost:{port}"


def test_only_authorised_stations_track(tmp_path: Path) -> None:
    make_certs(tmp_path, ["router", "arcf-service-1", "station-01", "station-02", "intruder"])
    conf, endpoint = router_config(tmp_path)
    seq = load_dataset("uav123_10fps", sequences=["wakeboard7"])[0]
    data = [p.read_bytes() for p in seq.frames[:4]]
    with zenoh.open(conf):
        svc = ServiceProcess("--zenoh-config",
                             str(peer_config(tmp_path, "arcf-service-1", endpoint)),
                             "--client-grace-s", "1", connect=endpoint, workers=1)
        try:
            station = zenoh.open(zenoh.Config.from_file(
                str(peer_config(tmp_path, "station-01", endpoint))))
            intruder = zenoh.open(zenoh.Config.from_file(
                str(peer_config(tmp_path, "intruder", endpoint))))
            # a second unauthorised peer listens and poses as the service (a separate session:
            # a session's own queryable would answer its own queries locally)
            impostor = zenoh.open(zenoh.Config.from_file(
                str(peer_config(tmp_path, "intruder", endpoint))))
            snooped: list[str] = []
            snoops = [impostor.declare_subscriber(k, lambda s: snooped.append(str(s.key_expr)))
                      for k in ("arcf/v1/**", "arcf/v1/streams/cam/frames",
                                "arcf/v1/streams/cam/sessions/*/results")]
            spoof = impostor.declare_queryable(
                "arcf/v1/control", lambda q: q.reply(q.key_expr, b"spoofed"))
            # the stimulus: the impostor's declarations have time to spread (nothing to wait
            # for: the router denies them; a slow machine only makes the checks below weaker)
            time.sleep(0.3)
            # every frame must be answered: the station publishes with BLOCK (with live
            # video's DROP, a stalled machine lets Zenoh drop one)
            with TrackingClient(session=station, frame_congestion="block") as good, \
                    TrackingClient(session=intruder) as bad:
                results = good.results("cam")
                ack = good.start("cam", seq.init_box, preset="bacf", frame_seq=0)
                replies = [r.ok.payload.to_bytes() for r in station.get(
                    "arcf/v1/control", payload=encode(StatusRequest(request_id="r1")),
                    target=zenoh.QueryTarget.ALL, timeout=2.0) if r.ok is not None]
                assert replies and all(isinstance(decode(r), Status) for r in replies)
                # the intruder can neither control sessions...
                with pytest.raises(TimeoutError):
                    bad.start("cam-x", seq.init_box, preset="bacf", timeout=1.0)
                with pytest.raises(TimeoutError):
                    bad.stop(ack.session_id, timeout=1.0)
                # an authorised station that did not start the session (no control token)
                # cannot stop or re-draw it either
                with TrackingClient(session=station, tie_sessions=False) as other:
                    for act in (lambda: other.stop(ack.session_id),
                                lambda: other.reinit(ack.session_id, seq.init_box)):
                        with pytest.raises(ServiceError) as refused:
                            act()
                        assert refused.value.code == "forbidden"
                # ...nor inject frames into a tracked stream, nor forge its results
                bad.publish_frame("cam", data=data[3], seq=1000)
                got = []
                for i, d in enumerate(data):
                    good.publish_frame("cam", data=d, seq=i)
                    got.append(results.get(timeout=10))
                    while got[-1].status.value == "stale":  # the wait above: no frames
                        got[-1] = results.get(timeout=10)
                # the stream is announced to stations (the live view's list); the intruder's
                # announcement reaches nobody, and it sees no one's
                def announced(c: TrackingClient) -> set[str]:
                    return {str(r.ok.key_expr) for r in c.session.liveliness().get(
                        c.keys.all_publisher_tokens(), timeout=2.0) if r.ok is not None}

                viewer = zenoh.open(zenoh.Config.from_file(
                    str(peer_config(tmp_path, "station-02", endpoint))))
                with TrackingClient(session=viewer, tie_sessions=False) as view:
                    assert view.streams() == ["cam"]  # another station's, through the router
                    assert announced(view) == {good.keys.publisher_token("cam", good.client_id)}
                viewer.close()
                # nobody else's (its own comes back from its own session, if in time: a
                # loaded machine's 2 s can pass without it)
                assert announced(bad) <= {bad.keys.publisher_token("cam", bad.client_id)}
                forged = got[-1].model_copy(update={"frame_seq": 999})
                intruder.put(good.keys.results("cam", ack.session_id), encode(forged))
                time.sleep(0.5)  # the window in which a forged result would arrive (none may)
                assert [r.frame_seq for r in got] == [0, 1, 2, 3]
                assert [r.status.value for r in got] == ["initialized"] + ["tracking"] * 3
                # nothing forged or injected arrived (the stream's stale notices may)
                assert all(r.status.value == "stale" and r.frame_seq == 3
                           for r in results.iter(timeout=0.5))
                good.stop(ack.session_id)
                results.close()
                assert svc.metric("arcf_frames_received_total") == 4
                # an H.264 stream nobody tracked yet: the box drawn on frame 5 (keyframes at 0
                # and 4) lands there, since the rules let the worker ask for the station's
                # recent units (zenoh-ext's @adv keys)
                units = encode_video([decode_compressed(d) for d in data * 2], gop=4)
                for i, unit in enumerate(units[:7]):
                    good.publish_frame("cam-video", data=unit, encoding="h264", seq=i)
                video = good.results("cam-video")
                good.start("cam-video", seq.init_box, preset="bacf", frame_seq=5)
                first = next_result(video, timeout=30)
                assert (first.frame_seq, first.status.value) == (5, "initialized")
                assert next_result(video, 5, timeout=30).frame_seq == 6
                # the station's liveliness token passes the rules: a service instance sees it
                # (a refused one would end the station's sessions after the 1 s grace)
                watcher = zenoh.open(zenoh.Config.from_file(
                    str(peer_config(tmp_path, "arcf-service-1", endpoint))))
                token = good.keys.client_token(good.client_id)
                wait_until(lambda: token in {str(r.ok.key_expr) for r in watcher.liveliness().get(
                    good.keys.all_client_tokens(), timeout=2.0) if r.ok is not None},
                           timeout=30, what="the station's token at a service instance")
                watcher.close()
                good.publish_frame("cam-video", data=units[7], encoding="h264", seq=7)
                last = next_result(video, 6, timeout=30)
                assert (last.frame_seq, last.status.value) == (7, "tracking")
                video.close()
            # ...nor read anyone's video or results
            assert snooped == []
            for sub in snoops:
                sub.undeclare()
            spoof.undeclare()
            impostor.close()
            station.close()
            intruder.close()
        finally:
            assert svc.stop() == 0
        # and without a client certificate, no connection at all (mutual TLS)
        with pytest.raises(zenoh.ZError):
            zenoh.open(zenoh.Config.from_file(str(peer_config(tmp_path, None, endpoint))))


def _rules(path: Path) -> tuple[list, list]:
    """A config file's access rules and policies (subjects aside)."""
    acl = zenoh.Config.from_file(str(path)).get_json("access_control")
    return json.loads(acl)["rules"], json.loads(acl)["policies"]


def direct_peer(d: Path, cn: str, endpoint: str) -> zenoh.Session:
    """A station as a Zenoh peer of the TLS deployment: it links to the workers' listeners the
    router's gossip names. It listens on nothing (only the workers do), so stations never link
    to each other."""
    conf = zenoh.Config.from_file(str(peer_config(d, cn, endpoint)))
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", "[]")
    return zenoh.open(conf)


def test_the_direct_path_holds_the_routers_rules(tmp_path: Path) -> None:
    """Workers listening for stations themselves (``--worker-listen``) check what the router
    checks (deploy/zenoh/service-direct-tls-acl.json5): an authorised station tracks over its
    direct link, and a station with a valid certificate but no rights, linked to the same
    worker, can neither inject frames nor read results there."""
    assert _rules(DEPLOY / "service-direct-tls-acl.json5") == _rules(
        DEPLOY / "router-tls-acl.json5")
    make_certs(tmp_path, ["router", "arcf-service-1", "station-01", "intruder"])
    conf, endpoint = router_config(tmp_path)
    service_conf = tmp_path / "service-direct.json5"
    service_conf.write_text(
        (DEPLOY / "service-direct-tls-acl.json5").read_text()
        .replace("tls/router.example.org:7447", endpoint)
        .replace("/certs/ca.pem", str(tmp_path / "ca.pem"))
        .replace("/certs/service.pem", str(tmp_path / "arcf-service-1.pem"))
        .replace("/certs/service-key.pem", str(tmp_path / "arcf-service-1-key.pem")))
    seq = load_dataset("uav123_10fps", sequences=["wakeboard7"])[0]
    data = [p.read_bytes() for p in seq.frames[:4]]
    with zenoh.open(conf):
        svc = ServiceProcess("--zenoh-config", str(service_conf),
                             "--worker-listen", "tls/127.0.0.1:0", connect=endpoint, workers=1)
        try:
            station = direct_peer(tmp_path, "station-01", endpoint)
            intruder = direct_peer(tmp_path, "intruder", endpoint)
            for peer in (station, intruder):  # each linked to the worker itself
                wait_for_peers(peer)
            with TrackingClient(session=station, frame_congestion="block") as good, \
                    TrackingClient(session=intruder) as bad:
                results = good.results("cam")
                ack = good.start("cam", seq.init_box, preset="bacf", frame_seq=0)
                snooped = bad.results("cam")
                got = []
                for i, d in enumerate(data):
                    good.publish_frame("cam", data=d, seq=i)
                    got.append(next_result(results, i - 1, timeout=30))
                    bad.publish_frame("cam", data=d, seq=1000 + i)  # denied at the worker
                assert [r.frame_seq for r in got] == [0, 1, 2, 3]
                assert [r.status.value for r in got] == ["initialized"] + ["tracking"] * 3
                good.stop(ack.session_id)
                # the worker counts what reached it: the station's four frames only
                assert svc.metric("arcf_frames_received_total") == 4
                assert list(snooped.iter(timeout=0.5)) == []
            station.close()
            intruder.close()
        finally:
            assert svc.stop() == 0
