import json

from typer.testing import CliRunner

from mptrack.cli import app

runner = CliRunner()


def test_reproduce_list_shows_registered_keys():
    result = runner.invoke(app, ["reproduce", "--list"])
    assert result.exit_code == 0, result.output
    assert "assimakis2014" in result.output and "assimakis2015" in result.output


def test_reproduce_writes_results(tmp_path):
    result = runner.invoke(app, ["reproduce", "assimakis2015", "--out", str(tmp_path), "--quick", "--quiet"])
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "assimakis2015" / "results.json").read_text())
    assert data["tables"]["Table 3"]["mismatches"] == []
    assert "published numbers reproduced" in result.output


def test_unknown_reproduction_is_a_clear_error(tmp_path):
    result = runner.invoke(app, ["reproduce", "nosuchpaper", "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert "unknown key 'nosuchpaper'" in result.output


def test_bench_quick_linear_writes_json(tmp_path):
    out = tmp_path / "bench.json"
    result = runner.invoke(app, ["bench", "--quick", "--suite", "linear", "--json", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())["reports"][0]
    assert report["suite"] == "linear"
    assert any(str(r[0]).startswith("implementation 12") for r in report["rows"])
