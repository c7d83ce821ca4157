"""The progress display that long work shares (a run's renders, calibration, sampling): label,
bar, n/N, elapsed time, info text."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


class _Silent:
    def update(self, **_) -> None:
        pass


class _Line:
    """Off a terminal (a log file, CI): no live bar, whose last frame rich cuts to 80 columns
    ("cali… converged: projected gradient ∞-norm ≤ gtol 0.01; 1 steps, 3 evaluations,…"), but one
    whole line when the block ends."""

    def __init__(self, completed: int, info: str = ""):
        self.completed, self.info = completed, info

    def update(self, completed: int | None = None, info: str | None = None) -> None:
        if completed is not None:
            self.completed = completed
        if info is not None:
            self.info = info


class _Bar:
    def __init__(self, progress, task):
        self._progress, self._task = progress, task

    def update(self, **fields) -> None:
        """``completed=``, ``info=`` (text after the bar)."""
        self._progress.update(self._task, **fields)


@contextmanager
def progress_bar(label: str, total: int, *, completed: int = 0, show: bool = True) -> Iterator[_Bar | _Line | _Silent]:
    """A rich progress display while the block runs (nothing when ``show`` is False; one line at
    the end when the output is not a terminal)."""
    if not show:
        yield _Silent()
        return
    import time

    from rich import get_console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    console = get_console()
    if not (console.is_terminal or console.is_jupyter):
        line, t0 = _Line(completed), time.perf_counter()
        try:
            yield line
        finally:
            info = f"; {line.info}" if line.info else ""
            console.print(
                f"{label}: {line.completed}/{total} in {time.perf_counter() - t0:.0f} s{info}",
                soft_wrap=True,
                markup=False,
                highlight=False,
            )
        return
    bar = Progress(
        TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("{task.fields[info]}")
    )
    task = bar.add_task(label, total=total, completed=completed, info="")
    with bar:
        yield _Bar(bar, task)


__all__ = ["progress_bar"]
