"""The programs the suite starts get what a user's terminal gives them: Ctrl-C reaches
them whether or not the suite was started in the background."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator

import pytest

from tests.helpers.processes import restore_sigint

SHOW_SIGINT = ("import signal; h = signal.getsignal(signal.SIGINT); "
               "print(getattr(h, 'name', None) or h.__name__)")


def sigint_in_a_child() -> str:
    return subprocess.run([sys.executable, "-c", SHOW_SIGINT], capture_output=True,
                          text=True, check=True, timeout=60).stdout.strip()


@pytest.fixture
def started_in_the_background() -> Iterator[None]:
    """SIGINT ignored, as a shell without job control leaves it for `pytest &`."""
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    yield
    signal.signal(signal.SIGINT, before)


def test_a_child_gets_ctrl_c_as_python_does_by_default() -> None:
    assert sigint_in_a_child() == "default_int_handler"


def test_a_suite_started_in_the_background_still_passes_ctrl_c_on(
        started_in_the_background: None) -> None:
    assert sigint_in_a_child() == "SIG_IGN"  # (what the children inherited before)
    restore_sigint()
    assert sigint_in_a_child() == "default_int_handler"
