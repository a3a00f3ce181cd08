"""Progress of long commands on stderr, with the interface of the library's null progress:
``with progress.task("Monte-Carlo", total=100) as advance: advance()``.

On a terminal a live rich bar; in a pipe or a log file one line when a task starts and one when it
ends (with its count and time), so every task of a long run shows up, not only the first.
"""

from __future__ import annotations

import contextlib
import time
from typing import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

__all__ = ["RichProgress", "LineProgress", "progress_for"]


class RichProgress:
    """A live progress bar (a terminal)."""

    def __init__(self, console: Console | None = None, disable: bool = False) -> None:
        self._progress = Progress(SpinnerColumn(), TextColumn("[bold]{task.description}"), BarColumn(),
                                  MofNCompleteColumn(), TimeElapsedColumn(),
                                  console=console, disable=disable, transient=False)

    def __enter__(self) -> "RichProgress":
        self._progress.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._progress.__exit__(*exc)

    @contextlib.contextmanager
    def task(self, description: str, total: int | None = None) -> Iterator[Callable[[int], None]]:
        task_id = self._progress.add_task(description, total=total)
        try:
            yield lambda advance=1: self._progress.advance(task_id, advance)
        finally:
            if total is not None:
                self._progress.update(task_id, completed=total)


class LineProgress:
    """Plain lines (a pipe, a log file): "TASK ..." when it starts, "TASK: N done in T s" when it ends."""

    def __init__(self, console: Console, disable: bool = False) -> None:
        self._console, self._disable = console, disable

    def __enter__(self) -> "LineProgress":
        return self

    def __exit__(self, *exc) -> None:
        return None

    def _line(self, text: str) -> None:
        if not self._disable:
            self._console.print(text, markup=False, highlight=False, soft_wrap=True)

    @contextlib.contextmanager
    def task(self, description: str, total: int | None = None) -> Iterator[Callable[[int], None]]:
        done = [0]
        start = time.perf_counter()
        self._line(f"{description} ..." + (f" ({total})" if total is not None else ""))

        def advance(n: int = 1) -> None:
            done[0] += n

        yield advance
        count = f"{total if total is not None else done[0]} " if total is not None or done[0] else ""
        self._line(f"{description}: {count}done in {time.perf_counter() - start:.1f} s")


def progress_for(console: Console, disable: bool = False):
    """The progress display that suits ``console``: a live bar on a terminal, lines otherwise."""
    if console.is_terminal:
        return RichProgress(console=console, disable=disable)
    return LineProgress(console, disable=disable)
