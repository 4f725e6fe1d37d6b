"""The LSL output (``lsl:``) through the installed gateway on gx2-sim, seen by an
independent pylsl inlet: every stream's name, type, channels, units, rate and
source_id, and each sample at the instant the ZeroMQ stream's ``time`` says, with the
same values, in order, with the gaps the radio left. All of it runs in a private
network namespace with only the loopback up (tests/helpers/lslnet.py): LSL discovers
by multicast, and nothing may reach the host's network; without one the test is
skipped. The rest needs no outlet: ``--check`` without liblsl, a gateway without
``lsl:`` that never imports pylsl, a bad ``lsl:`` section."""

from __future__ import annotations

import math
import socket
import subprocess
from pathlib import Path

import pytest
import yaml

from tests.helpers.lsl_replay_probe import LEAD, SAMPLES, STREAMS
from tests.helpers.lslnet import namespace_refusal, run_probe
from tests.helpers.ports import endpoint
from tests.helpers.processes import script

TOLERANCE_S = 1e-4
"""The inlet's timestamp, after time_correction(), against ``time``: 0.1 ms."""
NODES = [{"address": 76, "stream": "accel_angrate"},
         {"address": 77, "stream": "euler", "data_loss": 0.05}]
BROKEN_PYLSL = 'raise RuntimeError("LSL binary library file was not found.\\n More.")\n'
"""A pylsl whose import fails as pylsl's own does where no liblsl loads (aarch64)."""


@pytest.mark.usefixtures("favoured_host")  # (to 0.1 ms: 0.45 ms off once in a loaded suite)
def test_an_independent_inlet_finds_each_stream_with_its_metadata_and_the_sample_instants(
        tmp_path: Path) -> None:
    refusal = namespace_refusal()
    if refusal:
        pytest.skip(f"no private network namespace for LSL: {refusal}")
    found = run_probe("tests.helpers.lsl_probe",
                      {"seconds": 3.0, "nodes": NODES, "prefix": "lab7"}, tmp_path)
    assert found["exit"] == 0, found["log"]
    host = socket.gethostname()  # (only the network is unshared: the host name is ours)
    imu, euler = found["streams"]["lab7-76-accel_angrate"], found["streams"]["lab7-77-euler"]
    assert (imu["type"], imu["channel_count"], imu["nominal_srate"]) == ("IMU", 6, 100.0)
    assert [c["label"] for c in imu["channels"]] == [
        "accel_x", "accel_y", "accel_z", "ang_rate_x", "ang_rate_y", "ang_rate_z"]
    assert [c["unit"] for c in imu["channels"]] == ["g"] * 3 + ["rad/s"] * 3
    assert [c["type"] for c in imu["channels"]] == ["Acceleration"] * 3 + \
        ["AngularVelocity"] * 3
    assert imu["source_id"] == f"{host}/station1/76/accel_angrate"
    assert imu["channel_format"] == 1  # cf_float32
    assert imu["synchronization"]["can_drop_samples"] == "true"
    assert imu["synchronization"]["latency_ms"] == "3.0"
    assert (euler["type"], euler["channel_count"], euler["nominal_srate"]) == (
        "Orientation", 3, 100.0)
    assert [(c["label"], c["unit"]) for c in euler["channels"]] == [
        ("roll", "rad"), ("pitch", "rad"), ("yaw", "rad")]
    assert euler["source_id"] == f"{host}/station1/77/euler"

    for name, matched in found["matched"].items():
        assert matched.get("matched", 0) > 100, (name, matched)
        assert matched["values_differ"] == 0, (name, matched)  # the same records, in order
        assert matched["seq_last"] - matched["seq_first"] + 1 == matched["matched"]
        assert matched["time_error_max_s"] < TOLERANCE_S, (name, matched)
        # samples lost over the radio are gaps in the stream, never filled in
        assert matched["missing_inlet"] == matched["missing_records"], (name, matched)
    assert found["matched"]["lab7-76-accel_angrate"]["missing_records"] == 0
    assert found["matched"]["lab7-77-euler"]["missing_records"] > 3  # (5% of 300)
    status = found["status"]["lsl"]
    assert status["streams"] == ["lab7-76-accel_angrate", "lab7-77-euler"]
    assert status["dropped"] == 0 and status["pushed"] > 200, status
    assert status["skipped"] >= 2  # (each node's continuous_mode reply: no stream)
    assert found["status"]["outputs"]["lsl"] == {"take_failures": 0}


def test_a_replay_with_nan_and_without_the_derived_fields_loses_no_sample(
        tmp_path: Path) -> None:
    """A recording replayed with ``lsl:`` (tests/helpers/lsl_replay_probe.py): an
    Inertia-Link's NaN magnetometer (null in the file) and a file of before the matrix's
    derived fields, some of its values null. Every sample reaches the inlet: NaN in the
    channels the file holds null in, the roll, pitch, yaw and quaternion derived from
    the matrix (a null dropped its whole 20 ms batch, and a missing roll every
    sample: pushed 0)."""
    refusal = namespace_refusal()
    if refusal:
        pytest.skip(f"no private network namespace for LSL: {refusal}")
    found = run_probe("tests.helpers.lsl_replay_probe", {}, tmp_path, timeout=120)
    assert found["exit"] == 0, found["log"]
    mag, oriented = (found["samples"][name] for name in STREAMS)
    assert len(mag) == len(oriented) == SAMPLES, (len(mag), len(oriented), found["lsl"])
    status = found["lsl"]
    assert status["pushed"] == 2 * (LEAD + SAMPLES) and status["dropped"] == 0, status
    assert found["outputs"]["lsl"] == {"take_failures": 0}
    labels = found["labels"]
    assert labels[STREAMS[0]][6:] == ["mag_x", "mag_y", "mag_z"]
    assert all(all(math.isnan(v) for v in sample[6:]) and sample[2] == pytest.approx(-1.0)
               for sample in mag)
    assert labels[STREAMS[1]][-7:] == ["roll", "pitch", "yaw", "quaternion_w",
                                       "quaternion_x", "quaternion_y", "quaternion_z"]
    nan_x = [math.isnan(sample[0]) for sample in oriented]
    assert sum(nan_x) == SAMPLES // 5, sum(nan_x)  # (every fifth, null in the file)
    for sample in oriented:
        roll, pitch, yaw = sample[-7:-4]
        assert (roll, pitch) == pytest.approx((0.2, -0.1), abs=1e-6)
        assert -math.pi <= yaw <= math.pi and all(map(math.isfinite, sample[-4:]))


def config_file(directory: Path, **sections: object) -> Path:
    path = directory / "nodes.yaml"
    path.write_text(yaml.safe_dump({"base_station": {"port": "sim://"},
                                    "nodes": [{"address": 76}],
                                    "publish": {"endpoint": endpoint()},
                                    "control": {"endpoint": endpoint()}, **sections}))
    return path


def broken_pylsl(directory: Path) -> dict[str, str]:
    """An environment whose pylsl fails to load, as where no wheel ships liblsl."""
    (directory / "fake" / "pylsl").mkdir(parents=True)
    (directory / "fake" / "pylsl" / "__init__.py").write_text(BROKEN_PYLSL)
    return {"PYTHONPATH": str(directory / "fake"), "PATH": "/usr/bin:/bin"}


def test_check_says_in_one_line_how_to_install_liblsl(tmp_path: Path) -> None:
    path = config_file(tmp_path, lsl={"prefix": "gx2"})
    env = broken_pylsl(tmp_path)
    done = subprocess.run([script("gx2-gateway"), "--config", str(path), "--check"],
                          capture_output=True, text=True, env=env, timeout=30)
    assert done.returncode == 2, done
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert "pip install 'gx2-gateway[lsl]'" in lines[0] and "liblsl" in lines[0]
    started = subprocess.run([script("gx2-gateway"), "--config", str(path)],
                             capture_output=True, text=True, env=env, timeout=30)
    assert started.returncode == 1, started
    assert "Traceback" not in started.stderr
    assert "pip install 'gx2-gateway[lsl]'" in started.stderr.strip().splitlines()[-1]


def test_without_lsl_pylsl_is_never_imported(tmp_path: Path, gateway) -> None:
    env = broken_pylsl(tmp_path)
    done = subprocess.run([script("gx2-gateway"), "--config", str(config_file(tmp_path)),
                           "--check"], capture_output=True, text=True, env=env, timeout=30)
    assert done.returncode == 0, done.stderr
    gw = gateway("sim://", [{"address": 76, "stream": "accel_angrate"}], env=env)
    gw.wait_streaming(76)
    assert gw.status()["lsl"] is None
    assert "pylsl" not in gw.log() and "liblsl" not in gw.log()


@pytest.mark.parametrize(("lsl", "said"), [
    ({"prefix": "my lab"}, "lsl.prefix: 'my lab': 1 to 32 letters, digits"),
    ({"prefx": "lab"}, "lsl.prefx: unknown key (did you mean prefix?)"),
    ({"queue": 5}, "lsl.queue:"),
])
def test_a_bad_lsl_section_is_one_line(tmp_path: Path, lsl: dict, said: str) -> None:
    done = subprocess.run([script("gx2-gateway"), "--config",
                           str(config_file(tmp_path, lsl=lsl)), "--check"],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 2, done
    assert len(done.stderr.strip().splitlines()) == 1 and said in done.stderr, done.stderr
