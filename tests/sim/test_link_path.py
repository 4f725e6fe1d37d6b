"""gx2-sim --link PATH: made only where it takes nothing of anyone's, and removed only
while it is still its own (found by a new user: it replaced a regular file with its
symlink and deleted it on exit, and took over another running simulator's link)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

from tests.helpers.processes import Running

START = 30.0
"""Seconds allowed for the script to start and print its port (a loaded CI machine)."""


def run_sim(link: Path) -> Running:
    return Running("gx2-sim", "--nodes", "76", "--link", str(link))


def test_a_regular_file_is_refused_and_left_alone(tmp_path: Path) -> None:
    path = tmp_path / "mine.txt"
    path.write_text("my notes")
    sim = run_sim(path)
    try:
        assert sim.finish(START) == 2
    finally:
        sim.kill()
    assert path.read_text() == "my notes" and not path.is_symlink()
    assert len(sim.stderr) == 1 and "not a symlink" in sim.stderr[0], sim.stderr


def test_another_simulators_link_is_not_taken_over(tmp_path: Path) -> None:
    link = tmp_path / "gx2"
    first = run_sim(link)
    try:
        first.wait_for_line(lambda line: line == str(link), START)
        pty = os.readlink(link)
        second = run_sim(link)
        try:
            assert second.finish(START) == 2
            assert "not taken over" in "".join(second.stderr), second.stderr
        finally:
            second.kill()
        assert os.readlink(link) == pty, "the second simulator moved the link"
    finally:
        first.proc.send_signal(signal.SIGTERM)
        assert first.finish(START) == 0
    assert not link.is_symlink(), "the first simulator left its link behind"


def test_a_stale_link_is_taken_and_a_link_no_longer_ours_is_kept(tmp_path: Path) -> None:
    link = tmp_path / "gx2"
    link.symlink_to("/dev/pts/does-not-exist")  # left by a simulator that was killed
    sim = run_sim(link)
    try:
        sim.wait_for_line(lambda line: line == str(link), START)
        assert os.readlink(link).startswith("/dev/pts/")
        os.unlink(link)
        link.symlink_to(tmp_path / "someone-elses")  # replaced by someone meanwhile
        sim.proc.send_signal(signal.SIGTERM)
        assert sim.finish(START) == 0
    finally:
        sim.kill()
    assert os.readlink(link) == str(tmp_path / "someone-elses")
