"""The wheel a user installs (README, "Deploying"): built from this checkout it holds
every module and the files the deployment steps install, byte for byte; installed, its
``gx2-gateway --files`` finds them and its programs accept the shipped configurations.

Here the wheel is built offline (without isolation, by the setuptools the test extra
installs) and installed alone, on this environment's dependencies. CI (.ci/run) builds
it again as a user does, installs it with its dependencies into a fresh virtual
environment and runs the same commands there.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from gateway.daemon.shipped import SHIPPED
from tests.helpers.processes import spawn_run
from tests.test_deploy import deployment_steps

REPO = Path(__file__).resolve().parents[1]
NOT_SOURCES = shutil.ignore_patterns(".git", ".venv", ".hypothesis", ".*_cache", "__pycache__",
                                     "build", "dist", "*.egg-info")
"""What a copy of the checkout leaves out: what tools and builds leave behind."""
TIMEOUT = 120.0
"""Seconds a build or an install may take on a slow, shared machine."""


def shipped_files() -> dict[str, Path]:
    """The wheel's name for each file it ships -> the repository's file."""
    found = {}
    for name in SHIPPED:
        path = REPO / name
        for file in sorted(path.rglob("*")) if path.is_dir() else [path]:
            if file.is_file():
                found[f"gateway/share/{file.relative_to(REPO).as_posix()}"] = file
    return found


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Built as ``python -m build`` builds it: the sdist, then the wheel from the sdist.
    From a copy of the checkout, as the build writes beside its sources."""
    tmp = tmp_path_factory.mktemp("wheel")
    source = tmp / "source"
    shutil.copytree(REPO, source, symlinks=True, ignore=NOT_SOURCES)
    built = spawn_run([sys.executable, "-m", "build", "--no-isolation", "--outdir",
                       str(tmp / "dist"), str(source)], capture_output=True, text=True,
                      timeout=TIMEOUT, stdin=subprocess.DEVNULL)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    [path] = (tmp / "dist").glob("gx2_gateway-*.whl")
    return path


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel installed into a directory of its own (its programs in bin/), which
    PYTHONPATH puts ahead of this checkout's installation."""
    target = tmp_path_factory.mktemp("installed")
    done = spawn_run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                      "--no-index", "--target", str(target), str(wheel)],
                     capture_output=True, text=True, timeout=TIMEOUT,
                     stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done
    return target


def run(target: Path, name: str, *args: str, **env: str) -> subprocess.CompletedProcess:
    return spawn_run([str(target / "bin" / name), *args], capture_output=True, text=True,
                     timeout=60, stdin=subprocess.DEVNULL,
                     env={**os.environ, "PYTHONPATH": str(target), **env})


def test_the_wheel_holds_every_module_and_the_shipped_files(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        shipped = shipped_files()
        assert {"gateway/share/deploy/gx2-gateway.service",
                "gateway/share/deploy/99-gx2-basestation.rules",
                "gateway/share/deploy/gx2-alerts.yml", "gateway/share/deploy/grafana-gx2.json",
                "gateway/share/config/nodes.yaml",
                "gateway/share/config/demo.yaml", "gateway/share/README.md"} <= set(shipped)
        for name, file in shipped.items():
            assert name in names, name
            assert archive.read(name) == file.read_bytes(), f"{name} is not {file}"
    modules = {path.relative_to(REPO).as_posix() for package in ("aspp", "gateway")
               for path in (REPO / package).rglob("*.py") if "__pycache__" not in path.parts}
    assert modules - names == set()


def test_the_installed_wheel_finds_its_files_and_accepts_its_configurations(
        installed: Path, tmp_path: Path) -> None:
    for name in ("gx2-gateway", "gx2ctl", "gx2-sim"):
        done = run(installed, name, "--version")
        assert done.returncode == 0 and done.stdout.startswith(f"{name} "), done
    done = run(installed, "gx2-gateway", "--files")
    assert done.returncode == 0, done
    files = Path(done.stdout.strip())
    assert files == installed / "gateway" / "share"
    # nodes.yaml records to the unit's state directory: checked as the unit runs the
    # check, with systemd's $STATE_DIRECTORY (by hand, --check judges /var/lib/gx2-gateway
    # for the user running it, README says)
    # (sim.yaml's fourth node is one the gateway is not configured for, switched off)
    for name, program, nodes in (("demo.yaml", "gx2-gateway", 3),
                                 ("nodes.yaml", "gx2-gateway", 3), ("sim.yaml", "gx2-sim", 4)):
        config = files / "config" / name
        done = run(installed, program, "--config", str(config), "--check",
                   STATE_DIRECTORY=str(tmp_path))
        assert (done.returncode, done.stdout) == (0, f"{config}: valid ({nodes} nodes)\n"), done

    shutil.rmtree(files / "deploy")  # an installation broken by hand
    done = run(installed, "gx2-gateway", "--files")
    assert done.returncode == 1 and done.stdout == "", done
    assert done.stderr.startswith("gx2-gateway: ") and done.stderr.count("\n") == 1, done
    assert "lacks deploy" in done.stderr and "Traceback" not in done.stderr


def test_the_deployment_steps_install_the_wheel_and_what_it_ships() -> None:
    steps = deployment_steps()
    assert re.search(r"pip install gx2_gateway-\S*\.whl", steps), steps
    assert re.search(r'^files=\$\(\S+/bin/gx2-gateway --files\)', steps, re.MULTILINE), steps
    taken = re.findall(r'"\$files/([^"]+)"', steps)
    assert {"README.md", "config/nodes.yaml", "deploy/gx2-gateway.service",
            "deploy/99-gx2-basestation.rules"} <= set(taken), taken
    shipped = shipped_files()
    for name in taken:  # a file, or a directory of files
        assert f"gateway/share/{name}" in shipped or any(
            file.startswith(f"gateway/share/{name}/") for file in shipped), name
