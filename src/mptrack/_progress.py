"""Progress bars for long commands (rich), with the same interface as the library's null progress."""

from __future__ import annotations

import contextlib
from typing import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

__all__ = ["RichProgress"]


class RichProgress:
    """``with progress.task("Monte-Carlo", total=100) as advance: advance()``."""

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
