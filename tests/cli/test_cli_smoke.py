from typer.testing import CliRunner

from mptrack.cli import app


def test_filters_command_lists_all_twelve_implementations():
    result = CliRunner().invoke(app, ["filters"])
    assert result.exit_code == 0, result.output
    for name in ("KF-A", "JSSKLF-B", "FIR"):
        assert name in result.output
