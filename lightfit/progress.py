"""The progress display that long work shares (a run's renders, calibration, sampling): label,
bar, n/N, elapsed time, info text."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


class _Silent:
    def update(self, **_) -> None:
        pass


class _Bar:
    def __init__(self, progress, task):
        self._progress, self._task = progress, task

    def update(self, **fields) -> None:
        """``completed=``, ``info=`` (text after the bar)."""
        self._progress.update(self._task, **fields)


@contextmanager
def progress_bar(label: str, total: int, *, completed: int = 0, show: bool = True) -> Iterator[_Bar | _Silent]:
    """A rich progress display while the block runs (nothing when ``show`` is False)."""
    if not show:
        yield _Silent()
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    bar = Progress(
        TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("{task.fields[info]}")
    )
    task = bar.add_task(label, total=total, completed=completed, info="")
    with bar:
        yield _Bar(bar, task)


__all__ = ["progress_bar"]
