"""The ``mptrack`` command line: the only layer that imports typer and rich.  One module per command
group (tracking, reproduce, bench, filters, serve); each imports the library inside its commands, so
``mptrack --help`` loads no numerical library.

Exit status: 0 success, 1 internal error, 2 usage or data error, 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import os
import sys

# mptrack's matrices are small (n <= 10): BLAS threads only add synchronisation cost
# (milliseconds per call on a loaded machine). Parallelism is over tracks (numba).
# Set before NumPy is imported; a value the user exported is kept.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


import typer  # noqa: E402

from .. import __version__  # noqa: E402
from ._common import EXIT_CODES  # noqa: E402
from .bench import bench  # noqa: E402
from .filters import filters  # noqa: E402
from .reproduce import reproduce  # noqa: E402
from .serve import db, devices, geolocate, keys, serve  # noqa: E402
from .tracking import evaluate, simulate, track  # noqa: E402

__all__ = ["app", "main"]

#: Help on a terminal: rich panels as wide as the terminal.  In a pipe or a file: plain text, one line per
#: paragraph and per option (nothing wrapped at 80 columns), so it can be searched and reflowed.
_PIPED = not (hasattr(sys.stdout, "isatty") and sys.stdout.isatty())
_CONTEXT = {"help_option_names": ["-h", "--help"],
            **({"terminal_width": 100_000, "max_content_width": 100_000} if _PIPED else {})}

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  context_settings=_CONTEXT, rich_markup_mode=None if _PIPED else "rich",
                  help="mptrack: mobile-terminal position tracking and paper reproductions.",
                  epilog=EXIT_CODES + " Results go to stdout; progress, notes, advice and errors to stderr.")


def _version(value: bool) -> None:
    if value:
        print(f"mptrack {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", "-V", callback=_version, is_eager=True,
                                                 help="Print the version and exit.")) -> None:
    """mptrack: mobile-terminal position tracking and paper reproductions."""


for _command in (track, simulate, evaluate, reproduce, bench, filters, serve, geolocate):
    app.command(epilog=EXIT_CODES)(_command)
app.add_typer(devices, name="devices")
app.add_typer(keys, name="keys")
app.add_typer(db, name="db")


def main() -> None:  # pragma: no cover
    app()
