"""Progress of long commands on stderr, with the interface of the library's null progress:
``with progress.task("Monte-Carlo", total=100) as advance: advance()``.

On a terminal a live rich bar; in a pipe or a log file one line when a task starts and one when it
ends (with its count and time), so every task of a long run shows up, not only the first.

While it is shown, Ctrl-C raises KeyboardInterrupt as usual and is remembered: the next step a task
reports raises it again.  A library can swallow the exception -- numpy clears an error raised while it
compares a dtype, and pandas compares its string dtype so on every column lookup -- and a run then went
on to its end and exited 0 (seen in about one Ctrl-C in fifteen).
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from typing import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

__all__ = ["RichProgress", "LineProgress", "Interruptible", "progress_for"]


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


class Interruptible:
    """A progress display whose steps raise KeyboardInterrupt once Ctrl-C came (see the module doc)."""

    def __init__(self, display) -> None:
        self._display, self._seen, self._previous = display, False, None

    def __enter__(self) -> "Interruptible":
        self._display.__enter__()
        if threading.current_thread() is threading.main_thread() and \
                signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self._previous = signal.signal(signal.SIGINT, self._ctrl_c)
        return self

    def __exit__(self, *exc) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
        return self._display.__exit__(*exc)

    def _ctrl_c(self, signum, frame) -> None:
        self._seen = True
        raise KeyboardInterrupt

    @contextlib.contextmanager
    def task(self, description: str, total: int | None = None) -> Iterator[Callable[[int], None]]:
        with self._display.task(description, total) as advance:
            def step(n: int = 1) -> None:
                if self._seen:
                    raise KeyboardInterrupt
                advance(n)

            yield step


def progress_for(console: Console, disable: bool = False) -> Interruptible:
    """The progress display that suits ``console``: a live bar on a terminal, lines otherwise."""
    if console.is_terminal:
        return Interruptible(RichProgress(console=console, disable=disable))
    return Interruptible(LineProgress(console, disable=disable))
