"""``python -m mptrack``: the same as the ``mptrack`` command."""

from .cli import app

app(prog_name="mptrack")
