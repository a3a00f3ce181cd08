"""``python -m mptrack.cli``: the same as the ``mptrack`` command."""

from . import app

app(prog_name="mptrack")
