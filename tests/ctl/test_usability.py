"""gx2ctl, gx2-gateway and gx2-sim as a user types them: --version, a suggestion for a
mistyped command or record, the records each command takes in its help, and with
--json a failure as a JSON object on stdout too."""

from __future__ import annotations

import json

import pytest

from gateway.common.version import installed
from tests.helpers.processes import gx2ctl, script, spawn_run


@pytest.mark.parametrize("name", ["gx2ctl", "gx2-gateway", "gx2-sim"])
def test_every_program_says_its_version(name: str) -> None:
    run = spawn_run([script(name), "--version"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == f"{name} {installed()}", run


@pytest.mark.parametrize(("args", "hint"), [
    (["stauts"], "did you mean 'status'?"),
    (["eeprom", "raed", "76", "1"], "did you mean 'read'?"),
    (["poll", "76", "eulr"], "did you mean 'euler'?"),
    (["start", "76", "accel_angrat"], "did you mean 'accel_angrate'?"),
])
def test_a_mistyped_word_gets_a_suggestion(args: list[str], hint: str) -> None:
    ran = gx2ctl(*args)
    assert ran.status == 2 and hint in ran.stderr and len(ran.stderr.splitlines()) == 1, ran


@pytest.mark.parametrize(("command", "listed", "absent"), [
    ("poll", ["euler", "temperatures", "firmware_version"], ["device_id", "eeprom_read"]),
    ("start", ["euler", "accel_angrate"], ["firmware_version", "continuous_mode"]),
])
def test_help_lists_the_records_a_command_takes(command: str, listed: list[str],
                                                absent: list[str]) -> None:
    text = " ".join(gx2ctl(command, "--help").stdout.split())
    for name in listed:
        assert name in text, name
    for name in absent:
        assert name not in text, name


def test_with_json_a_failure_is_a_json_object_on_stdout_too() -> None:
    ran = gx2ctl("--json", "--control", "tcp://127.0.0.1:9", "--timeout", "0.3", "status")
    assert ran.status == 3 and ran.stderr.startswith("gx2ctl: no answer")
    answer = json.loads(ran.stdout)
    assert answer["ok"] is False and answer["exit"] == 3 and "no answer" in answer["error"]
