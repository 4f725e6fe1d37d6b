"""deploy/gx2-gateway.service as README's deployment steps install it: the gateway it
runs records, and where it records the unit lets it write (issue 20: under
``ProtectSystem=strict`` with no writable directory it recorded nothing, silently)."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
from pathlib import Path, PurePosixPath

import pytest

from gateway.daemon.config import RecordConfig, load_config
from tests.helpers.processes import script

REPO = Path(__file__).resolve().parents[1]
UNIT = REPO / "deploy" / "gx2-gateway.service"

# systemd.exec(5), "RuntimeDirectory=, StateDirectory=, ...", table 2: where a system
# unit's directories are made (writable by its user whatever ProtectSystem= says); a
# name may be followed by ":" and a symlink to it. ReadWritePaths= takes absolute paths,
# each perhaps prefixed with "-" (ignored if missing) or "+" (outside RootDirectory=).
DIRECTORY_ROOTS = {"RuntimeDirectory": "/run", "StateDirectory": "/var/lib",
                   "CacheDirectory": "/var/cache", "LogsDirectory": "/var/log"}


def service_settings(text: str) -> dict[str, list[str]]:
    """The [Service] section: each key's values in order. A key may be given more than
    once (DeviceAllow=), and an empty assignment resets a list (systemd.unit(5))."""
    settings: dict[str, list[str]] = {}
    section = ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
        elif section == "Service":
            key, _, value = line.partition("=")
            values = settings.setdefault(key.strip(), [])
            if value.strip():
                values.append(value.strip())
            else:
                values.clear()
    return settings


def writable_paths(settings: dict[str, list[str]]) -> list[PurePosixPath]:
    paths = [PurePosixPath(root, word.split(":")[0])
             for key, root in DIRECTORY_ROOTS.items()
             for value in settings.get(key, []) for word in value.split()]
    return paths + [PurePosixPath(word.lstrip("-+"))
                    for value in settings.get("ReadWritePaths", []) for word in value.split()]


def state_directory(settings: dict[str, list[str]]) -> str:
    """$STATE_DIRECTORY as systemd sets it for the unit: the paths, joined by ":"."""
    return ":".join(str(PurePosixPath("/var/lib", word.split(":")[0]))
                    for value in settings.get("StateDirectory", []) for word in value.split())


def deployment_steps() -> str:
    """The shell block of the "Deploying" section of docs/operating.md."""
    page = (REPO / "docs" / "operating.md").read_text()
    section = page.split("\n## Deploying", 1)[1].split("\n## ", 1)[0]
    return section.split("```sh\n", 1)[1].split("```", 1)[0]


def within(path: str, roots: list[PurePosixPath]) -> bool:
    return any(PurePosixPath(path).is_relative_to(root) for root in roots)


def test_the_gateway_records_where_the_unit_lets_it_write(monkeypatch):
    settings = service_settings(UNIT.read_text())
    roots = writable_paths(settings)
    assert settings["ProtectSystem"] == ["strict"]
    assert state_directory(settings), "the unit has no StateDirectory="

    # the default, under the unit (systemd sets $STATE_DIRECTORY) and by hand (not set)
    monkeypatch.setenv("STATE_DIRECTORY", state_directory(settings))
    under_unit = RecordConfig().directory
    installed = load_config(REPO / "config" / "nodes.yaml").record
    monkeypatch.delenv("STATE_DIRECTORY")
    by_hand = RecordConfig().directory
    assert within(under_unit, roots), (under_unit, roots)
    assert within(by_hand, roots), (by_hand, roots)
    # and the configuration README installs records, there
    assert installed is not None, "config/nodes.yaml records nothing"
    assert within(installed.directory, roots), (installed.directory, roots)


def test_the_unit_runs_what_readme_installs():
    steps = deployment_steps()
    settings = service_settings(UNIT.read_text())
    venv = re.search(r"python3 -m venv (\S+)", steps)
    config = re.search(r"install .*config/nodes\.yaml\"? (\S+)", steps)
    user = re.search(r"useradd .* (\S+)\n", steps)
    assert venv and config and user, steps
    assert re.search(r"cp \S*deploy/gx2-gateway\.service\"? /etc/systemd/system/", steps), steps
    assert settings["User"] == [user[1]]
    commands = {key: shlex.split(settings[key][0].lstrip("-+!@:"))
                for key in ("ExecStart", "ExecStartPre")}
    for key, argv in commands.items():
        assert argv[0] == f"{venv[1]}/bin/gx2-gateway", (key, argv)
        assert argv[argv.index("--config") + 1] == config[1], (key, argv)
    # the check runs as the unit's user in its sandbox: it judges the recording directory
    # as the gateway will find it
    assert "--check" in commands["ExecStartPre"]


def test_systemd_analyze_verifies_the_unit(tmp_path):
    """What this proves: systemd (this machine's version) knows every key, parses every
    value, and finds the commands executable. It runs nothing, so not the sandbox."""
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed (package systemd)")
    # the installed gx2-gateway stands in for the one README installs under /opt, which
    # verify would otherwise report missing; nothing else in the unit changes
    command = shlex.split(service_settings(UNIT.read_text())["ExecStart"][0])[0]
    unit = tmp_path / UNIT.name
    unit.write_text(UNIT.read_text().replace(command, script("gx2-gateway")))
    run = subprocess.run([analyze, "verify", "--man=no", str(unit)], capture_output=True,
                         text=True, timeout=30, stdin=subprocess.DEVNULL)
    # unknown keys and unparsable values are only warned about (exit 0, systemd 252):
    # every line naming the unit counts
    complaints = [line for line in run.stderr.splitlines() if UNIT.name in line]
    if run.returncode != 0 and not complaints:
        pytest.skip(f"systemd-analyze verify cannot run here: {run.stderr.strip()}")
    assert run.returncode == 0 and complaints == [], run.stderr
