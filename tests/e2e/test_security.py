"""Who may control the gateway and read its data: loopback or ipc:// by default, CURVE
with an allow-list of client keys otherwise, and key files that keep their secrets.
Through the installed console scripts and real ZeroMQ sockets."""

from __future__ import annotations

import os
import stat
import subprocess
from pathlib import Path

import pytest
import yaml

from gateway.common import curve
from gateway.common.curve import ClientKeys
from gateway.daemon.config import ConfigError, load_config
from gateway.sim.node import NodeSettings
from tests.helpers.gateway import Control, Subscriber
from tests.helpers.ports import free_port
from tests.helpers.processes import STARTUP, script, spawn_run
from tests.helpers.waiting import wait_for


def run(name: str, *args: str, cwd: Path | None = None, umask: int | None = None
        ) -> subprocess.CompletedProcess:
    return spawn_run([script(name), *args], capture_output=True, text=True, timeout=30,
                     cwd=cwd, preexec_fn=(lambda: os.umask(umask)) if umask is not None
                     else None)


def one_line(done: subprocess.CompletedProcess, status: int) -> str:
    assert done.returncode == status, done
    assert "Traceback" not in done.stderr and done.stderr.count("\n") == 1, done.stderr
    return done.stderr


def write_config(path: Path, control: str, **sections: object) -> Path:
    # (a publish endpoint of its own: the default is the demo's, and --check warns that
    # it is held while a user runs the demo beside the suite)
    path.write_text(yaml.safe_dump({
        "base_station": {"port": "sim://"}, "control": {"endpoint": control},
        "publish": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
        "nodes": [{"address": 76}], **sections}))
    return path


# --- endpoints --------------------------------------------------------------------------

@pytest.mark.parametrize("endpoint", [
    "tcp://127.0.0.1:5556", "tcp://127.3.4.5:5556", "tcp://localhost:5556",
    "tcp://[::1]:5556", "ipc:///run/gx2-gateway/control", "ipc://@gx2-control",
])
def test_local_control_endpoints_need_no_keys(tmp_path: Path, endpoint: str) -> None:
    assert load_config(write_config(tmp_path / "n.yaml", endpoint)).control.endpoint == endpoint


@pytest.mark.parametrize("endpoint", [
    "tcp://0.0.0.0:5556", "tcp://*:5556", "tcp://192.168.1.20:5556", "tcp://eth0:5556",
    "tcp://gateway.example.org:5556", "tcp://[::]:5556",
])
def test_a_control_endpoint_other_hosts_may_reach_is_refused_without_curve(
        tmp_path: Path, endpoint: str) -> None:
    with pytest.raises(ConfigError, match=r"control\.endpoint: .*configure curve"):
        load_config(write_config(tmp_path / "n.yaml", endpoint))


def test_the_refusal_is_one_line_from_the_daemon(tmp_path: Path) -> None:
    path = write_config(tmp_path / "n.yaml", "tcp://0.0.0.0:5556")
    line = one_line(run("gx2-gateway", "--config", str(path), "--check"), 2)
    assert line.startswith(f"gx2-gateway: {path}: control.endpoint: tcp://0.0.0.0:5556")


# --- keys -------------------------------------------------------------------------------

def test_keygen_writes_a_private_pair_and_never_overwrites(tmp_path: Path) -> None:
    done = run("gx2ctl", "keygen", str(tmp_path / "ops"), umask=0)  # the worst umask
    assert done.returncode == 0, done
    public, secret = tmp_path / "ops.key", tmp_path / "ops.key_secret"
    assert stat.S_IMODE(public.stat().st_mode) == 0o644
    assert stat.S_IMODE(secret.stat().st_mode) == 0o600
    pair = curve.load_key_pair(secret)
    assert curve.public_key(str(public)) == pair.public
    assert pair.public.decode() in done.stdout and pair.secret.decode() not in done.stdout
    before = secret.read_bytes()
    line = one_line(run("gx2ctl", "keygen", str(tmp_path / "ops")), 1)
    assert "already exists" in line and secret.read_bytes() == before


def test_keys_that_cannot_serve_are_config_errors(tmp_path: Path) -> None:
    curve.generate(tmp_path / "server")
    curve.generate(tmp_path / "ops")
    cases = {
        "a public file as the server key": ({"server_key": str(tmp_path / "server.key"),
                                             "clients": [str(tmp_path / "ops.key")]},
                                            "holds no secret-key"),
        "a missing client key": ({"server_key": str(tmp_path / "server.key_secret"),
                                  "clients": ["not-a-key"]}, "curve.clients: \\[0\\]"),
        "no clients": ({"server_key": str(tmp_path / "server.key_secret"), "clients": []},
                       "curve.clients"),
    }
    for name, (section, problem) in cases.items():
        path = write_config(tmp_path / "n.yaml", "tcp://0.0.0.0:5556", curve=section)
        with pytest.raises(ConfigError, match=problem):
            load_config(path)
            pytest.fail(name)
    (tmp_path / "server.key_secret").chmod(0o644)
    path = write_config(tmp_path / "n.yaml", "tcp://0.0.0.0:5556", curve={
        "server_key": str(tmp_path / "server.key_secret"), "clients": [str(tmp_path / "ops.key")]})
    line = one_line(run("gx2-gateway", "--config", str(path), "--check"), 2)
    assert "readable by every user is not secret" in line


# --- a gateway with CURVE ---------------------------------------------------------------

@pytest.fixture
def keys(tmp_path: Path) -> dict[str, Path]:
    for name in ("server", "ops", "stranger"):
        curve.generate(tmp_path / name)
    return {name: tmp_path / f"{name}.key_secret" for name in ("server", "ops", "stranger")}


def client_keys(keys: dict[str, Path], who: str) -> ClientKeys:
    return ClientKeys(curve.load_key_pair(keys[who]), curve.load_key_pair(keys["server"]).public)


def test_curve_lets_in_only_the_allowed_keys(simulator, gateway, zmq_context, keys, tmp_path):
    """Control on every interface, as CURVE allows: the allowed client is served, the
    data stream reaches only an allowed subscriber, and the others get nothing."""
    sim = simulator(NodeSettings(76))
    port = free_port()
    gw = gateway(sim.path, [{"address": 76, "stream": "euler"}], wait=False,
                 control={"endpoint": f"tcp://0.0.0.0:{port}"},
                 curve={"server_key": str(keys["server"]),
                        "clients": [str(keys["ops"]).removesuffix("_secret")]})
    endpoint = f"tcp://127.0.0.1:{port}"
    ops = Control(zmq_context, endpoint, client_keys(keys, "ops"))
    wait_for(lambda: ops.try_call("status", timeout=0.5), STARTUP, "an answer to ops")
    gw.control = ops
    gw.wait_streaming(76)

    allowed = Subscriber(zmq_context, gw.publish_endpoint, "gx2/76/",
                         keys=client_keys(keys, "ops"))
    plain = Subscriber(zmq_context, gw.publish_endpoint, "gx2/76/")
    stranger = Subscriber(zmq_context, gw.publish_endpoint, "gx2/76/",
                          keys=client_keys(keys, "stranger"))
    allowed.until(lambda m: len(m) >= 100, 10, "records for the allowed subscriber")
    assert plain.drain(0.05) == [] and stranger.drain(0.05) == []

    for control in (Control(zmq_context, endpoint),
                    Control(zmq_context, endpoint, client_keys(keys, "stranger"))):
        assert control.try_call("status", timeout=1.0) is None
    assert ops.result("status")["gateway"]["curve_denied"] >= 2

    def gx2ctl(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
        return spawn_run([script("gx2ctl"), "--config", str(gw.path), "--timeout", "2", *args],
                         capture_output=True, text=True, timeout=30,
                         env={**os.environ, **(env or {})})
    done = gx2ctl("--client-key", str(keys["ops"]), "ping", "76")
    assert (done.returncode, done.stdout) == (0, "76 answered\n"), done
    done = gx2ctl("poll", "76", "euler", env={"GX2_CLIENT_KEY": str(keys["ops"])})
    assert done.returncode == 0 and '"record": "euler"' in done.stdout, done
    assert "allowed" in one_line(gx2ctl("--client-key", str(keys["stranger"]), "status"), 3)
    assert "--client-key" in one_line(gx2ctl("status"), 2)


def test_an_ipc_control_socket_is_for_its_owner_and_group(simulator, gateway, zmq_context,
                                                          tmp_path):
    sim = simulator(NodeSettings(76))
    path = tmp_path / "control"
    gw = gateway(sim.path, [{"address": 76}], control={"endpoint": f"ipc://{path}"})
    assert stat.S_IMODE(path.stat().st_mode) == 0o660
    done = run("gx2ctl", "--control", f"ipc://{path}", "ping", "76")
    assert (done.returncode, done.stdout) == (0, "76 answered\n"), done
    assert gw.status()["gateway"]["control_endpoint"] == f"ipc://{path}"


# --- MQTT credentials -------------------------------------------------------------------

PASSWORD = "S3cretPassw0rd"
URLS_WITH_A_PASSWORD = (f"mqtt://lab:{PASSWORD}#x@broker.lab:1883",
                        f"mqtt://lab:S3c/{PASSWORD}@broker.lab:1883",
                        f"mqtt://lab:S3c?{PASSWORD}@broker.lab:1883",
                        f"lab:{PASSWORD}@broker.lab:1883")
"""Urls whose ``@`` urlsplit puts outside the netloc: each was shown whole."""


@pytest.mark.parametrize("mqtt", [
    {"url": f"mqtt://lab:{PASSWORD}@broker.lab:1883"},
    {"url": f"mqtt://lab:{PASSWORD}@broker.lab:1883", "usrname": "lab"},  # and a bad key
    {"url": f"mqtt://lab:{PASSWORD}@broker..lab:1883"},
    *({"url": url} for url in URLS_WITH_A_PASSWORD),
])
def test_a_password_in_the_mqtt_url_is_never_printed_by_check(tmp_path: Path,
                                                              mqtt: dict) -> None:
    """The url's user and password are refused (they are mqtt.username and
    mqtt.password) in one line that says neither: the url's repr, userinfo included,
    was in the error; so was a url whose password urlsplit does not see (a ``#``, ``/``
    or ``?`` in it, no scheme: 'the scheme is lab')."""
    path = write_config(tmp_path / "n.yaml", f"tcp://127.0.0.1:{free_port()}", mqtt=mqtt)
    line = one_line(run("gx2-gateway", "--config", str(path), "--check"), 2)
    assert PASSWORD not in line and "//lab" not in line and "'lab'" not in line, line
    assert "mqtt." in line and "***@broker" in line, line


def test_a_reload_refused_for_a_password_in_the_url_says_it_nowhere(gateway) -> None:
    """``gx2ctl reload``'s answer and the gateway's log say why the file was refused,
    never the password in it."""
    gw = gateway("sim://", [{"address": 76, "stream": "accel_angrate"}])
    urls = (f"mqtt://lab:{PASSWORD}@broker.lab:1883", *URLS_WITH_A_PASSWORD)
    for n, url in enumerate(urls, 1):
        gw.path.write_text(yaml.safe_dump({**gw.config, "mqtt": {"url": url}}))
        done = run("gx2ctl", "--control", gw.control_endpoint, "reload")
        assert done.returncode != 0 and "reload refused" in done.stderr, done
        assert "mqtt.url" in done.stderr, done.stderr
        assert PASSWORD not in done.stdout + done.stderr, url
        wait_for(lambda n=n: gw.log().count("reload refused") >= n, 5,
                 "the refusal logged")
    assert PASSWORD not in gw.log()


def test_credentials_sent_in_the_clear_to_another_host_are_one_warning_in_check(
        tmp_path: Path) -> None:
    """A user and password over plain mqtt:// to a host that is not this one: --check
    passes, saying so in one warning line (as the start does); not over mqtts://, nor
    to the loopback."""
    said = []
    for url, user in (("mqtt://broker.lab:1883", "lab"), ("mqtts://broker.lab", "lab"),
                      ("mqtt://127.0.0.1:1883", "lab"), ("mqtt://broker.lab", None)):
        mqtt = {"url": url, **({"username": user, "password": PASSWORD} if user else {})}
        path = write_config(tmp_path / "n.yaml", f"tcp://127.0.0.1:{free_port()}",
                            mqtt=mqtt)
        done = run("gx2-gateway", "--config", str(path), "--check")
        assert done.returncode == 0, done
        assert PASSWORD not in done.stdout + done.stderr
        said.append(done.stderr.splitlines())
    (warning,), *others = said
    assert warning.startswith("gx2-gateway: warning: ") and "unencrypted" in warning
    assert "mqtts://" in warning and "broker.lab" in warning, warning
    assert others == [[], [], []]
