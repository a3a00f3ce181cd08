"""What every command shares: the consoles (results on stdout, progress and messages on stderr), the
-q/-v options, JSON output, one-line errors and the exit codes.

Exit codes: 0 success; 1 an internal error (a bug: the traceback is printed); 2 a usage or data error
(one line naming the option, file, row or column); 130 interrupted (Ctrl-C; one line saying what was
kept).
"""

from __future__ import annotations

import contextlib
import json
import shlex
import shutil
import sys
from pathlib import Path
from typing import Iterable, Iterator

import typer
from rich.console import Console
from rich.markup import escape

from ..errors import MptrackError, ParameterError, UnknownNameError

__all__ = ["out", "err", "QUIET", "VERBOSE", "JSON", "fail", "interrupted", "command_line", "print_json",
           "progress", "reject", "reject_given", "given", "flag", "flags_named", "FLAGS", "check_outputs", "EXIT_CODES", "echo",
           "note", "PAPERS", "paper_names", "fmt", "short_paper"]

EXIT_CODES = "Exit status: 0 success, 1 internal error, 2 usage or data error, 130 interrupted."


def _console(stream) -> Console:
    """A console for ``stream``: styled on a terminal; plain, unwrapped and untruncated otherwise
    (a pipe or a file gets whole lines and full numbers)."""
    tty = stream.isatty() if hasattr(stream, "isatty") else False
    if tty:
        return Console(file=stream, soft_wrap=True)
    return Console(file=stream, soft_wrap=True, width=100_000, no_color=True, highlight=False)


class _LazyConsole:
    """The console of sys.stdout/sys.stderr as they are when used (test runners replace them)."""

    def __init__(self, name: str) -> None:
        self._name = name

    @property
    def console(self) -> Console:
        return _console(getattr(sys, self._name))

    def __getattr__(self, attr):
        return getattr(self.console, attr)


out = _LazyConsole("stdout")
err = _LazyConsole("stderr")

QUIET = typer.Option(False, "--quiet", "-q", help="Quiet: print nothing but errors (a list command: the names "
                                                   "only; with --json: the JSON only).")
VERBOSE = typer.Option(False, "--verbose", "-v", help="More detail: notes, examples, every table row.")
JSON = typer.Option(False, "--json", help="Print the result as JSON on stdout (full precision; nothing else "
                                           "on stdout).")


def echo(text: str) -> None:
    """A result line on stdout, as is (no markup, no wrapping)."""
    out.print(escape(text), highlight=False, soft_wrap=True)


def note(text: str, label: str = "note") -> None:
    """A message on stderr."""
    err.print(f"[yellow]{label}:[/yellow] {escape(text)}", highlight=False, soft_wrap=True)


def reason(exc: BaseException) -> str:
    if isinstance(exc, MptrackError) or not isinstance(exc, OSError):
        return str(exc)
    if exc.filename is not None and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return (str(exc).splitlines() or [type(exc).__name__])[0]


def fail(exc: BaseException | str, kept: str = "") -> None:
    """One line on stderr and exit status 2: an MptrackError's message, or an OSError's path and cause."""
    text = exc if isinstance(exc, str) else reason(exc)
    err.print(f"[red]error:[/red] {escape(text + kept)}", highlight=False, soft_wrap=True)
    raise typer.Exit(2)


def reject(option: str, why: str) -> None:
    """An option that does not apply to this run: one line, exit status 2."""
    fail(f"{option} {why}")


#: The library's names of settings that the command line spells otherwise (every other name ``n`` is the
#: option ``--n`` with dashes): the one place that maps what an error names to what the user typed.
FLAGS = {"sigma_m": "--sigma", "gate_probability": "--gate", "r_km2": "--range-sigma", "duration_s": "--duration",
         "speed_mps": "--speed", "outlier_rate": "--outliers", "accuracy_column": "--accuracy/--no-accuracy",
         "tolerance_s": "--tolerance", "max_workers": "--workers", "max_gap_s": "--max-gap"}


def flag(name: str) -> str:
    """The command-line option of a library argument (``sigma_m`` -> ``--sigma``)."""
    return FLAGS.get(name, "--" + name.replace("_", "-"))


def check_outputs(*inputs, **outputs) -> None:
    """:func:`mptrack._core.data_checks.check_outputs` with the outputs named by their options, so a clash
    reads "--report: r.html is also given as --out"."""
    from .._core.data_checks import check_outputs as check

    check(*inputs, **{flag(name): path for name, path in outputs.items()})


def _option(ctx, name: str):
    """The option of the running command that sets ``name`` (its parameter name, or the library argument it
    becomes: ``sigma_m`` -> the parameter of ``--sigma``), or None."""
    if ctx is None:
        return None
    params = {p.name: p for p in ctx.command.params}
    return params.get(name) or params.get(flag(name).split("/")[0].removeprefix("--").replace("-", "_"))


def _spelling(ctx, option) -> str:
    """An option as the user typed it: its long form (``--out`` for ``-o``); of a switch, the form that
    gave its value (``--no-accuracy`` for False)."""
    forms = option.secondary_opts if option.secondary_opts and ctx.params.get(option.name) is False else option.opts
    return next((o for o in forms if o.startswith("--")), forms[0])


def given(ctx, names: Iterable[str]) -> list[str]:
    """The options among ``names`` (parameter or library names) that the user gave, on the command line or in
    the environment (not left at their defaults), as typed (:func:`_spelling`)."""
    found = []
    for name in names:
        option = _option(ctx, name)
        source = ctx.get_parameter_source(option.name) if option is not None else None
        if source is not None and source.name in ("COMMANDLINE", "ENVIRONMENT"):
            found.append(_spelling(ctx, option))
    return found


def reject_given(ctx, names: Iterable[str], why: str) -> None:
    """Refuse the first of the options ``names`` the user gave (:func:`given`): it does not apply to this
    run, ``why`` says when it does (one line, exit status 2). Never ignore an option silently."""
    for option in given(ctx, names)[:1]:
        reject(option, why)


@contextlib.contextmanager
def flags_named(ctx) -> Iterator[None]:
    """Errors of the library about an argument that an option of this command sets ("sigma_m: expected
    ...") name the option the user typed ("--sigma: expected ..."); other errors pass unchanged."""
    try:
        yield
    except (ParameterError, UnknownNameError) as exc:
        name, sep, rest = str(exc).partition(":")
        option = _option(ctx, name) if sep and name.isidentifier() else None
        if option is None:
            raise
        raise type(exc)(f"{_spelling(ctx, option)}:{rest}") from None


def interrupted(what: str) -> None:
    """Ctrl-C: one line saying what was kept, exit status 130."""
    err.print(escape(f"interrupted; {what}"), highlight=False, soft_wrap=True)
    raise typer.Exit(130)


def _shortest(path: str) -> str:
    """A program's path as typed: its bare name when the shell finds this very file by that name."""
    name = Path(path).name
    found = shutil.which(name)
    return name if found and Path(found).absolute() == Path(path).absolute() else path


def command_line(resume: bool = False) -> str:
    """This run's command line as the user can type it again (in the same directory), with ``--resume``
    added when asked."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is not None and spec.name.startswith("mptrack"):  # python -m mptrack.cli ...
        head = [_shortest(sys.executable), "-m", spec.name.removesuffix(".__main__")]
    else:
        head = [_shortest(sys.argv[0])]
    args = sys.argv[1:]
    return shlex.join(head + args + (["--resume"] if resume and "--resume" not in args else []))


def print_json(data) -> None:
    """``data`` as JSON on stdout, numbers at full precision."""
    sys.stdout.write(json.dumps(data, indent=2, default=str, allow_nan=True) + "\n")
    sys.stdout.flush()


def progress(quiet: bool):
    """Progress on stderr: a live bar on a terminal, one line per finished task otherwise."""
    from ._progress import progress_for

    return progress_for(err.console, disable=quiet)


#: The papers as users know them (author and year, as :func:`short_paper` writes them: one or two authors
#: by name, three or more "First et al."), for text that still calls them by file number.
PAPERS = {"000": "Assimakis & Adam 2014", "001": "Assimakis et al. 2016", "002": "Assimakis & Adam 2015",
          "003": "Bouzera et al. 2017", "004": "Zhao et al. 2013"}


def paper_names(text: str) -> str:
    """``text`` with a citation by the papers' internal file numbers (the word "seed" and 000-004, as
    results stored by earlier versions have them) replaced by the paper's authors and year."""
    import re

    return re.sub(r"\bseeds? (00[0-4])\b", lambda m: PAPERS[m.group(1)], text)


def fmt(v) -> str:
    """A number for a terminal table: 6 significant digits on a terminal, every digit in a pipe."""
    if isinstance(v, float):
        return f"{v:.6g}" if out.console.is_terminal else repr(v)
    return "—" if v is None else str(v)


def short_paper(paper: str) -> str:
    """"Assimakis & Adam (2014), Global Systems ..." -> "Assimakis & Adam 2014"; three or more authors
    -> "First et al. YEAR"."""
    import re

    m = re.match(r"\s*(.*?)\s*\((\d{4})\)", paper)
    if not m:
        return paper.split(",")[0]
    authors = re.split(r",\s*|\s+&\s+|\s+and\s+", m.group(1))
    names = authors[0] if len(authors) == 1 else " & ".join(authors) if len(authors) == 2 else f"{authors[0]} et al."
    return f"{names} {m.group(2)}"
