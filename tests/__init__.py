"""The test suite: a package, so its helpers are importable (``tests.helpers``), by the
tests and by the hand-run scripts in ``bench/``."""
