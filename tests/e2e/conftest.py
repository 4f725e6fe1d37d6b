"""The end-to-end tests' programs run at a favoured niceness (processes.PROGRAMS)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.helpers.processes import PROGRAMS, favoured


@pytest.fixture(autouse=True)
def programs_favoured(request: pytest.FixtureRequest) -> Iterator[None]:
    """Each test's simulator, gateway and gx2ctl above the suite's in-process work; a
    test that asks for ``favoured_host`` (a timing test) gets that, higher still."""
    if "favoured_host" in request.fixturenames:
        yield
        return
    with favoured(PROGRAMS):
        yield
