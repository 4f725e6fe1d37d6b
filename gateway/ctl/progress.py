"""export's progress bar (:mod:`.offline`): the bytes of the recordings read, on a
terminal only."""

from __future__ import annotations

from typing import Any


class ProgressBar:
    """rich's progress bar over the bytes of the recordings, on a terminal only (the
    messages read advance it by their size, a fair share of the file's)."""

    def __init__(self, total: int, terminal: bool) -> None:
        self._progress: Any = None
        self._task: Any = None
        self._total = max(total, 1)
        if terminal:
            from rich.progress import Progress
            self._progress = Progress(transient=True)
            self._task = self._progress.add_task("exporting", total=self._total)

    def advance(self, size: int) -> None:
        """``size`` bytes of messages read (about twice their share of the file)."""
        if self._progress is not None:
            self._progress.advance(self._task, size // 2)

    def __enter__(self) -> ProgressBar:
        if self._progress is not None:
            self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()
