"""The configuration file as gx2-gateway reads it: every kind of mistake is one line
and exit 2, never a traceback; --check validates exactly what start-up does."""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import types
import typing
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest
import yaml
from pydantic import BaseModel

from gateway.common import curve
from gateway.daemon.config import ConfigError, GatewayConfig, load_config
from tests.helpers.ports import free_port
from tests.helpers.processes import script, spawn_run
from tests.helpers.waiting import wait_for

REPO = Path(__file__).resolve().parents[2]
CLI_TIMEOUT = 45.0
"""Seconds a `gx2-gateway` run with a bad configuration may take before it counts as hung
(half a second alone; in the suite run in 4 processes on two cores shared with another
run, runs with their line printed were still running at 15 s, 8 of them started at once)."""
POOL = os.cpu_count() or 2
"""Runs at once: one a core, the suite's other processes running beside them."""


# -- 8. invalid configuration files ----------------------------------------------------------------

def valid_config() -> dict[str, Any]:
    return {"base_station": {"port": "/dev/gx2-test-no-such-port", "baudrate": 115200},
            "publish": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
            "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}",
                        "allow_eeprom_write": False},
            "nodes": [{"address": 76, "name": "left-wing", "stream": "accel_angrate"},
                      {"address": 77}]}


def _same_endpoints(config: dict[str, Any]) -> None:
    config["publish"]["endpoint"] = config["control"]["endpoint"]


BAD_CONFIGS: dict[str, tuple[Any, list[str]]] = {
    # name: (change to a valid config, patterns the one stderr line must match)
    "unknown-top-level-key": (lambda c: c.update(bogus=1), [r"\bbogus\b", r"unknown"]),
    "unknown-base-station-key": (lambda c: c["base_station"].update(baud=9600),
                                 [r"base_station\.baud\b", r"unknown"]),
    "address-is-a-string": (lambda c: c["nodes"][0].update(address="76"),
                            [r"nodes\[0\]\.address", r"integer"]),
    "baudrate-is-a-word": (lambda c: c["base_station"].update(baudrate="fast"),
                           [r"base_station\.baudrate", r"integer"]),
    "address-0": (lambda c: c["nodes"][0].update(address=0),
                  [r"nodes\[0\]\.address", r"greater than or equal to 1|1\.\.65534"]),
    "address-65535": (lambda c: c["nodes"][0].update(address=65535),
                      [r"nodes\[0\]\.address", r"65534"]),
    "flag-is-a-word": (lambda c: c.setdefault("control", {}).update(allow_eeprom_write="yes"),
                       [r"control\.allow_eeprom_write", r"boolean"]),
    "baudrate-as-text": (lambda c: c["base_station"].update(baudrate="115200"),
                         [r"base_station\.baudrate", r"integer"]),
    "unknown-port-scheme": (lambda c: c["base_station"].update(port="bogus://x"),
                            [r"base_station\.port", r"bogus"]),
    "endpoint-without-port": (lambda c: c["publish"].update(endpoint="tcp://127.0.0.1"),
                              [r"publish\.endpoint", r"endpoint"]),
    "key-given-twice": ("base_station: {port: x}\nnodes: [{address: 3}]\n"
                        "nodes: [{address: 4}]\n", [r"line 3", r"nodes", r"twice"]),
    "duplicate-address": (lambda c: c["nodes"][1].update(address=76),
                          [r"nodes\[1\]\.address", r"\b76\b", r"already|duplicate|twice"]),
    "unknown-stream-record": (lambda c: c["nodes"][0].update(stream="sideways"),
                              [r"nodes\[0\]\.stream", r"sideways", r"unknown"]),
    "record-not-streamable": (lambda c: c["nodes"][0].update(stream="eeprom_read"),
                              [r"nodes\[0\]\.stream", r"eeprom_read", r"stream"]),
    # (nodes: [] is valid: a gateway with no nodes yet, to scan the channel: test_scan.py)
    "missing-base-station": (lambda c: c.pop("base_station"),
                             [r"\bbase_station\b", r"missing|required"]),
    "publish-equals-control": (_same_endpoints,
                               [r"publish\.endpoint", r"control\.endpoint", r"differ|same"]),
    "endpoint-not-zeromq": (lambda c: c["publish"].update(endpoint="5555"),
                            [r"publish\.endpoint", r"'?5555'?", r"endpoint"]),
    "sim-unknown-parameter": (lambda c: c["base_station"].update(port="sim://?bogus=1"),
                              [r"base_station\.port", r"\bbogus\b"]),
    "sim-parameter-out-of-range": (
        lambda c: c["base_station"].update(port="sim://?garbage=2"),
        [r"base_station\.port", r"\bgarbage\b"]),
    "metrics-endpoint-a-url": (lambda c: c.update(metrics={"endpoint": "http://host:9105"}),
                               [r"metrics\.endpoint", r"HOST:PORT"]),
    "metrics-port-out-of-range": (lambda c: c.update(metrics={"endpoint": "127.0.0.1:70000"}),
                                  [r"metrics\.endpoint", r"1\.\.65535"]),
    "metrics-ipv6-without-brackets": (lambda c: c.update(metrics={"endpoint": "::1:9105"}),
                                      [r"metrics\.endpoint", r"\[::1\]:9105"]),
    "health-unknown-key": (lambda c: c.update(health={"rssi": -80}),
                           [r"health\.rssi", r"unknown"]),
    "health-window-negative": (lambda c: c.update(health={"window_s": -1}),
                               [r"health\.window_s", r"greater than or equal to 2"]),
    "record-unknown-key": (lambda c: c.update(record={"keep_gbs": 10}),
                           [r"record\.keep_gbs", r"unknown"]),
    "record-keep-gb-zero": (lambda c: c.update(record={"keep_gb": 0}),
                            [r"record\.keep_gb\b", r"greater than 0"]),
    "record-keep-days-a-word": (lambda c: c.update(record={"keep_days": "month"}),
                                [r"record\.keep_days", r"number"]),
    "yaml-syntax-error": ("base_station: {port: [/dev/ttyUSB0\nnodes: - 76\n",
                          [r"line \d+"]),
    "impossible-date": ("base_station: {port: sim://}\nnodes: [76]\nwhen: 2026-02-30\n",
                        [r"day is out of range"]),
    "nested-too-deeply": ("nodes: " + "[" * 5000 + "]" * 5000 + "\n",
                          [r"nested too deeply"]),
    "no-such-file": (None, [r"[Nn]o such file|does not exist|cannot read"]),
    "a-directory": ("directory", [r"[Ii]s a directory|cannot read"]),
}


def run_gateway(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``gx2-gateway ARGS``; a run that outlives CLI_TIMEOUT is reported with returncode
    None (it took a bad configuration and started serving)."""
    command = [script("gx2-gateway"), *args]
    try:
        return spawn_run(command, capture_output=True, text=True, timeout=CLI_TIMEOUT,
                         stdin=subprocess.DEVNULL, env=env)
    except subprocess.TimeoutExpired as expired:
        return subprocess.CompletedProcess(command, None, _text(expired.stdout),  # type: ignore[arg-type]
                                           _text(expired.stderr))


def _text(output: bytes | str | None) -> str:
    """What a run cut short by its timeout wrote: bytes, whatever ``text=`` said."""
    return output.decode(errors="replace") if isinstance(output, bytes) else output or ""


def write_bad_config(directory: Path, name: str, change: Any) -> Path:
    path = directory / f"{name}.yaml"
    if change is None:
        return path  # never written
    if change == "directory":
        path.mkdir()
    elif isinstance(change, str):
        path.write_text(change)
    else:
        config = valid_config()
        change(config)
        path.write_text(yaml.safe_dump(config))
    return path


def one_line_problems(run: subprocess.CompletedProcess, path: Path,
                      patterns: list[str]) -> list[str]:
    """What is wrong with a run that should have rejected ``path`` (empty: nothing)."""
    problems = []
    if run.returncode != 2:
        problems.append(f"exit status {run.returncode}, not 2")
    lines = run.stderr.splitlines()
    if len(lines) != 1:
        problems.append(f"{len(lines)} lines on stderr, not 1")
    if "Traceback" in run.stderr:
        problems.append("a traceback")
    text = lines[0] if lines else ""
    if str(path) not in text:
        problems.append("the file is not named")
    problems += [f"no match for {p!r}" for p in patterns if not re.search(p, text)]
    if run.stdout:
        problems.append(f"stdout {run.stdout!r}")
    return [f"{p}; stderr: {run.stderr!r}" for p in problems[:1]] + problems[1:]


THROUGH_THE_PROGRAM = ("unknown-top-level-key", "key-given-twice", "yaml-syntax-error",
                       "nested-too-deeply", "no-such-file")
"""The mistakes also made through the installed gx2-gateway: a model's, the YAML
reader's, the parser's own limit and the file system's. The rest are judged by the
loader the program calls (what it prints is ``gx2-gateway: `` and the error): a run
of the program each cost half a second of CPU, 33 of them a CPU-bound test of 27 s."""


def loaded(path: Path) -> subprocess.CompletedProcess:
    """What gx2-gateway makes of ``path`` at start-up, as a finished run: its loader's
    error as the program prints it (gateway.daemon.cli), exit 2; exit 0 if it loads."""
    try:
        load_config(path)
    except ConfigError as error:
        return subprocess.CompletedProcess(["load_config"], 2, "", f"gx2-gateway: {error}\n")
    return subprocess.CompletedProcess(["load_config"], 0, "", "")


def test_invalid_configuration_files(tmp_path):
    cases = {name: (write_bad_config(tmp_path, name, change), patterns)
             for name, (change, patterns) in BAD_CONFIGS.items()}
    valid = tmp_path / "valid.yaml"
    valid.write_text(yaml.safe_dump(valid_config()))
    with ThreadPoolExecutor(max_workers=POOL) as pool:
        runs = {name: pool.submit(run_gateway, "--config", str(cases[name][0]))
                for name in THROUGH_THE_PROGRAM}
        check = pool.submit(run_gateway, "--config", str(valid), "--check")
        no_config = pool.submit(run_gateway)
        failures = {}
        for name, (path, patterns) in cases.items():
            problems = one_line_problems(loaded(path), path, patterns)
            if name in runs:
                problems += one_line_problems(runs[name].result(), path, patterns)
            if problems:
                failures[name] = problems
        check_run, usage_run = check.result(), no_config.result()
    assert failures == {}, "\n".join(f"{k}: {v}" for k, v in failures.items())

    assert check_run.returncode == 0, check_run
    assert len(check_run.stdout.splitlines()) == 1, check_run
    assert str(valid) in check_run.stdout
    # (its port, a device not plugged in: a warning, test_check_warns_of_...)
    assert [line for line in check_run.stderr.splitlines()
            if "warning" not in line] == [], check_run

    assert usage_run.returncode == 2, usage_run
    assert len(usage_run.stderr.splitlines()) == 1, usage_run
    assert "--config" in usage_run.stderr and "Traceback" not in usage_run.stderr


# -- booleans: true or false, nothing else ---------------------------------------------------------
# YAML 1.1 (PyYAML's) reads yes, no, on and off as booleans; the interface says `yes` is
# not one (issue 31): each is refused where a boolean goes, naming the key.

def boolean_keys(model: type[BaseModel], where: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every boolean key of ``model`` and of its sections, as paths."""
    found = []
    for name, field in model.model_fields.items():
        kinds = (typing.get_args(field.annotation)
                 if isinstance(field.annotation, types.UnionType) else (field.annotation,))
        for kind in kinds:
            if kind is bool:
                found.append((*where, name))
            elif isinstance(kind, type) and issubclass(kind, BaseModel):
                found += boolean_keys(kind, (*where, name))
    return found


def with_word(config: dict[str, Any], keys: list[tuple[str, ...]], word: str) -> str:
    """``config`` as YAML with ``word`` written bare (unquoted) at each of ``keys``."""
    for key in keys:
        section = config
        for part in key[:-1]:
            section = section.setdefault(part, {})
        section[key[-1]] = "WORD-HERE"
    return yaml.safe_dump(config).replace("WORD-HERE", word)


def test_only_true_and_false_are_booleans(tmp_path):
    curve.generate(tmp_path / "server")
    curve.generate(tmp_path / "ops")
    keys = boolean_keys(GatewayConfig)
    assert {"control.allow_eeprom_write", "shutdown.stop_streams", "curve.publish"} <= \
        {".".join(key) for key in keys}, keys

    def config() -> dict[str, Any]:
        # (each section whose booleans are tried, with its required keys)
        return {**valid_config(), "curve": {"server_key": str(tmp_path / "server.key_secret"),
                                             "clients": [str(tmp_path / "ops.key")]},
                "mqtt": {"url": "mqtt://127.0.0.1:1883"}}
    # every key given the word at once: the one line names each key it refuses (one
    # run a word, not one a key and word: 6 start-ups of the gateway, not 30)
    runs = {}
    with ThreadPoolExecutor(max_workers=POOL) as pool:
        for word in ("yes", "on", "No", "OFF", "true", "False"):
            path = tmp_path / f"{word}.yaml"
            path.write_text(with_word(config(), keys, word))
            runs[word, path] = pool.submit(run_gateway, "--config", str(path), "--check")
        sim = tmp_path / "sim.yaml"
        sim.write_text("line: {glue_ack: yes}\nnodes: [{address: 76, radio: {in_range: on}}]\n")
        sim_run = pool.submit(spawn_run, [script("gx2-sim"), "--config", str(sim), "--check"],
                              capture_output=True, text=True, timeout=CLI_TIMEOUT)
        failures = {}
        for (word, path), future in runs.items():
            run = future.result()
            if word in ("true", "False"):
                if run.returncode != 0:
                    failures[word] = run.stderr
                continue
            problems = one_line_problems(run, path, [
                re.escape(f"{'.'.join(key)}: ") + "[^;]*write true or false[^;]*"
                + re.escape(repr(word)) for key in keys])
            if problems:
                failures[word] = problems
    assert failures == {}, "\n".join(f"{k}: {v}" for k, v in failures.items())
    assert one_line_problems(sim_run.result(), sim, [r"line\.glue_ack: ",
                                                     "write true or false, not 'yes'"]) == []


# -- a typo is said first --------------------------------------------------------------------------
# An unknown key is most often a typo, and the cause of the other problems near it (the
# key it should have been is missing): it is said first, with the key it is close to
# (issue 31: `node:` in a station said `base_stations[0].nodes: required key is missing
# (and 1 more)`). The others follow it, every one (issue 43).

def _stations_with(typo: str) -> Any:
    def change(config: dict[str, Any]) -> None:
        del config["base_station"], config["nodes"]
        config["base_stations"] = [{"port": "sim://", "nodes": [{"address": 76}]},
                                   {"port": "sim://", typo: [{"address": 77}]}]
    return change


def _renamed(section: str | None, old: str, new: str, index: int | None = None) -> Any:
    def change(config: dict[str, Any]) -> None:
        where = config if section is None else config[section]
        where = where[index] if index is not None else where
        where[new] = where.pop(old)
    return change


TYPOS: dict[str, tuple[Any, str]] = {
    # (change to a valid config, what the one line must say right after the file)
    "node for nodes in a station": (_stations_with("node"),
                                    r"base_stations\[1\]\.node: unknown key \(did you mean "
                                    r"nodes\?\); base_stations\[1\]\.nodes: required key is "
                                    r"missing$"),
    "nodez for nodes": (_renamed(None, "nodes", "nodez"),
                        r"nodez: unknown key \(did you mean nodes\?\)$"),
    "base_staton": (_renamed(None, "base_station", "base_staton"),
                    r"base_staton: unknown key \(did you mean base_station\?\)$"),
    "adress in a node": (_renamed("nodes", "address", "adress", 0),
                         r"nodes\[0\]\.adress: unknown key \(did you mean address\?\); "
                         r"nodes\[0\]\.address: required key is missing$"),
    "a key like no other": (lambda c: c["control"].update(zzz=1),
                            r"control\.zzz: unknown key \(a typo\?\)$"),
}


def test_a_typo_is_said_first_with_the_key_it_may_be(tmp_path):
    paths = {name: write_bad_config(tmp_path, name.replace(" ", "-"), change)
             for name, (change, _) in TYPOS.items()}
    sim = tmp_path / "sim.yaml"
    sim.write_text("nodes: [{adress: 76}]\n")
    with ThreadPoolExecutor(max_workers=POOL) as pool:
        runs = {name: pool.submit(run_gateway, "--config", str(path), "--check")
                for name, path in paths.items()}
        sim_run = pool.submit(spawn_run, [script("gx2-sim"), "--config", str(sim), "--check"],
                              capture_output=True, text=True, timeout=CLI_TIMEOUT)
        failures = {name: problems for name, future in runs.items()
                    if (problems := one_line_problems(
                        future.result(), paths[name],
                        [re.escape(f"{paths[name]}: ") + TYPOS[name][1]]))}
    assert failures == {}, "\n".join(f"{k}: {v}" for k, v in failures.items())
    assert one_line_problems(sim_run.result(), sim, [
        r"nodes\[0\]\.adress: unknown key \(did you mean address\?\)"]) == []


def test_every_problem_is_said_and_a_stream_is_offered_only_streamable_records(tmp_path):
    """Two mistakes are two said, on the one line (issue 43: ``(and 1 more)``); an
    unknown record where a stream is asked for lists the records that can stream, not
    ``eeprom_write`` or ``built_in_test``."""
    def change(config: dict[str, Any]) -> None:
        config["base_station"]["baudrate"] = "fast"
        config["nodes"][1]["stream"] = "eulr"
    path = write_bad_config(tmp_path, "two-mistakes", change)
    run = run_gateway("--config", str(path), "--check")
    assert one_line_problems(run, path, [
        r"base_station\.baudrate: [^;]*integer; nodes\[1\]\.stream: unknown record 'eulr'; "
        r"did you mean 'euler'\? known: .*\beuler_angrate\b"]) == [], run
    known = run.stderr.split("known: ")[1].strip().split(", ")
    assert "euler" in known and "accel_angrate" in known, known
    assert not {"eeprom_write", "built_in_test", "device_id", "store_nonvolatile"} & set(
        known), known


def test_check_rejects_a_bad_sim_port(tmp_path):
    """``--check`` validates the configuration (0: valid, 2: not): it must not pass a file
    the daemon then rejects at start-up with exit 2."""
    names = ("sim-unknown-parameter", "sim-parameter-out-of-range")
    paths = {n: write_bad_config(tmp_path, n, BAD_CONFIGS[n][0]) for n in names}
    with ThreadPoolExecutor(max_workers=2) as pool:
        runs = {n: pool.submit(run_gateway, "--config", str(p), "--check")
                for n, p in paths.items()}
        failures = {n: problems for n, future in runs.items()
                    if (problems := one_line_problems(future.result(), paths[n],
                                                      BAD_CONFIGS[n][1]))}
    assert failures == {}, "\n".join(f"{k}: {v}" for k, v in failures.items())


def test_rejected_sim_port_leaves_no_temporary_directory(tmp_path):
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    path = write_bad_config(tmp_path, "bad-sim", BAD_CONFIGS["sim-unknown-parameter"][0])
    run = run_gateway("--config", str(path), env={**os.environ, "TMPDIR": str(temporary)})
    assert run.returncode == 2, run
    assert sorted(p.name for p in temporary.iterdir()) == [], \
        "the embedded simulator's directory was left behind"


def test_a_metrics_port_in_use_stops_the_start_up_with_one_line(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        config = valid_config()
        config["metrics"] = {"endpoint": f"127.0.0.1:{port}"}
        path = tmp_path / "nodes.yaml"
        path.write_text(yaml.safe_dump(config))
        run = run_gateway("--config", str(path))
    assert run.returncode == 1, run
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr, run
    assert f"cannot bind 127.0.0.1:{port}: " in run.stderr, run


# -- what --check says of this host: warnings, exit 0 --------------------------------------------
# A device not plugged in yet, an endpoint another process holds (most often the gateway
# this file is about to replace): a start would meet them, so --check says so, one line
# each on stderr; the file is valid all the same (issue 31).

def check_warnings(run: subprocess.CompletedProcess, path: Path) -> list[str]:
    """The warning lines of a --check that passed."""
    assert run.returncode == 0 and run.stdout == f"{path}: valid (2 nodes)\n", run
    lines = run.stderr.splitlines()
    assert all(line.startswith(f"gx2-gateway: warning: {path}: ") for line in lines), run
    assert "Traceback" not in run.stderr
    return lines


def test_check_warns_of_a_device_that_does_not_exist(tmp_path):
    path = tmp_path / "nodes.yaml"
    path.write_text(yaml.safe_dump(valid_config()))
    [line] = check_warnings(run_gateway("--config", str(path), "--check"), path)
    assert "base_station.port: /dev/gx2-test-no-such-port does not exist" in line, line

    stations = {**valid_config(), "base_stations": [
        {"port": "sim://", "nodes": [{"address": 76}]},
        {"port": str(tmp_path / "unplugged"), "nodes": [{"address": 77}]}]}
    del stations["base_station"], stations["nodes"]
    path.write_text(yaml.safe_dump(stations))
    run = run_gateway("--config", str(path), "--check")
    assert run.returncode == 0 and "valid (2 nodes on 2 base stations)" in run.stdout, run
    [line] = run.stderr.splitlines()
    assert f"base_stations[1].port: {tmp_path / 'unplugged'} does not exist" in line, line


def test_check_warns_of_endpoints_another_process_holds(tmp_path, zmq_context):
    import zmq

    ipc = tmp_path / "control"
    holder = zmq_context.socket(zmq.ROUTER)
    holder.setsockopt(zmq.LINGER, 0)
    holder.bind(f"ipc://{ipc}")
    listeners = []
    for _ in range(3):
        listener = socket.socket()
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        listeners.append(listener)
    try:
        publish, metrics, live = (f"127.0.0.1:{s.getsockname()[1]}" for s in listeners)
        config = {**valid_config(), "base_station": {"port": "sim://"},
                  "publish": {"endpoint": f"tcp://{publish}"},
                  "control": {"endpoint": f"ipc://{ipc}"},
                  "metrics": {"endpoint": metrics}, "live": {"endpoint": live}}
        path = tmp_path / "nodes.yaml"
        path.write_text(yaml.safe_dump(config))
        lines = check_warnings(run_gateway("--config", str(path), "--check"), path)
        held = {line.split(": ")[3]: line for line in lines}
        assert sorted(held) == ["control.endpoint", "live.endpoint", "metrics.endpoint",
                                "publish.endpoint"], lines
        assert all("held by another process" in line for line in lines), lines
        # the ipc:// endpoint was only looked at: still the holder's (ZeroMQ's bind would
        # have taken its path)
        with socket.socket(socket.AF_UNIX) as peer:
            peer.connect(str(ipc))
    finally:
        for listener in listeners:
            listener.close()
        holder.close()
    # let go (the ipc path left behind, stale): nothing to warn of
    assert check_warnings(run_gateway("--config", str(path), "--check"), path) == []


# -- the recording directory -----------------------------------------------------------------------
# --check runs as the unit's ExecStartPre, as its user and in its sandbox: a directory the
# gateway cannot write must fail there (exit 2, one line), not leave a recorder that keeps
# nothing while everything says all is well (issue 20).

def record_config(path: Path, record: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump({**valid_config(), "record": record}))
    return path


def test_check_refuses_a_recording_directory_that_cannot_be_created(tmp_path):
    """Under a regular file: no one can make it, root included."""
    afile = tmp_path / "afile"
    afile.write_text("")
    cases = {"under-a-file": (afile / "recordings",
                              rf"cannot be created: {re.escape(str(afile))} is not a directory$"),
             "a-file": (afile, rf"{re.escape(str(afile))}: is not a directory$")}
    failures = {}
    for name, (directory, pattern) in cases.items():
        path = record_config(tmp_path / f"{name}.yaml", {"directory": str(directory)})
        run = run_gateway("--config", str(path), "--check")
        problems = one_line_problems(run, path, [r"record\.directory", pattern])
        if problems:
            failures[name] = problems
    assert failures == {}, failures


def read_only_directory(tmp_path: Path) -> tuple[list[str], Path]:
    """(a command prefix, a directory it makes read-only for everyone): a read-only
    tmpfs in a mount namespace of the command's own (unshare(1)), which denies root too
    and vanishes with it; for another user without namespaces, mode 0555. Skips where
    neither can be had."""
    directory = tmp_path / "read-only"
    directory.mkdir()
    why = "unshare(1) is not installed"
    unshare = shutil.which("unshare")
    if unshare:
        shell = 'mount -t tmpfs -o ro gx2-test "$1" && shift && exec "$@"'
        prefix = [unshare, "--user", "--map-root-user", "--mount", "sh", "-c", shell, "sh",
                  str(directory)]
        probe = spawn_run([*prefix, "true"], capture_output=True, text=True, timeout=10)
        if probe.returncode == 0:
            return prefix, directory
        why = probe.stderr.strip()
    if os.geteuid() != 0:
        directory.chmod(0o555)
        return [], directory
    pytest.skip(f"no read-only directory for root: {why}")


def test_check_refuses_a_recording_directory_it_cannot_write(tmp_path):
    prefix, read_only = read_only_directory(tmp_path)
    reason = r"not writable by user \S+ \((Read-only file system|Permission denied)\)$"
    cases = {"existing": (read_only, rf"{re.escape(str(read_only))}: is {reason}"),
             "missing": (read_only / "recordings",
                         rf"cannot be created: {re.escape(str(read_only))} is {reason}")}
    failures = {}
    for name, (directory, pattern) in cases.items():
        path = record_config(tmp_path / f"{name}.yaml", {"directory": str(directory)})
        run = spawn_run([*prefix, script("gx2-gateway"), "--config", str(path), "--check"],
                        capture_output=True, text=True, timeout=CLI_TIMEOUT,
                        stdin=subprocess.DEVNULL)
        problems = one_line_problems(run, path, [r"record\.directory", pattern])
        if problems:
            failures[name] = problems
    assert failures == {}, failures


def test_the_default_directory_is_the_units_state_directory(tmp_path):
    """``record:`` with no keys (YAML null) or ``{}`` records in
    ``$STATE_DIRECTORY/recordings``; --check judges that directory and creates nothing."""
    (tmp_path / "afile").write_text("")
    state = tmp_path / "state"
    state.mkdir()
    bare = tmp_path / "bare.yaml"
    bare.write_text(yaml.safe_dump(valid_config()) + "record:\n")
    empty = record_config(tmp_path / "empty.yaml", {})
    env = {**os.environ, "STATE_DIRECTORY": str(state)}
    for path in (bare, empty):
        run = run_gateway("--config", str(path), "--check", env=env)
        assert run.returncode == 0 and "valid" in run.stdout, run
    assert list(state.iterdir()) == [], "--check left something in the state directory"

    refused = run_gateway("--config", str(bare), "--check",
                          env={**os.environ, "STATE_DIRECTORY": str(tmp_path / "afile")})
    assert one_line_problems(refused, bare, [
        rf"record\.directory: {re.escape(str(tmp_path / 'afile' / 'recordings'))}: "
        "cannot be created"]) == []


def test_record_with_no_keys_records_in_the_state_directory(gateway, tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    gw = gateway("sim://", [{"address": 76, "stream": "euler"}], record={},
                 env={**os.environ, "STATE_DIRECTORY": str(state)})
    recordings = state / "recordings"
    assert gw.status()["recording"]["directory"] == str(recordings)
    wait_for(lambda: list(recordings.glob("*.mcap")), 10, "a recording in the state directory")
    status, _ = gw.terminate()
    assert status == 0, gw.log()
