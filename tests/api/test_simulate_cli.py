"""``demcal simulate``: one JSON object on stdout with the documented keys, and ``--set`` errors
that exit 2 naming the option."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from api.cli import app

TINY = """
[items]
counts = { smartphone = 1, camera = 1 }
[stages]
insertion_time = 0.1
vibration_start = 0.4
vibration_time = 0.4
"""


def test_json_is_one_object_with_the_documented_keys(tmp_path):
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    result = CliRunner().invoke(app, ["simulate", str(config), "--json", "--seed", "5", "--set", "mu=0.4"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)  # exactly one JSON document, nothing else on stdout
    assert {
        "n_remaining", "n_items", "discharge_times", "wall_time_s", "cost", "steps", "dt", "status",
        "message", "params", "seed", "version",
    } <= set(data)  # fmt: skip
    assert data["status"] == "ok" and data["seed"] == 5 and data["n_items"] == 2
    assert data["params"]["mu"] == 0.4 and data["params"]["E"] == 1e7  # --set, then the config default
    assert len(data["discharge_times"]) == 2
    assert data["n_remaining"] == sum(t is None for t in data["discharge_times"])
    # No steps while the tray is still empty (t < first insertion), one per dt afterwards.
    assert 0.9 * data["sim_time"] / data["dt"] < data["steps"] <= data["sim_time"] / data["dt"] + 1


def test_bad_set_exits_2_naming_it(tmp_path):
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    for option, fragment in [("E=soft", "E must be a number"), ("G=1", "unknown key"), ("mu", "KEY=VALUE")]:
        result = CliRunner().invoke(app, ["simulate", str(config), "--json", "--set", option])
        assert result.exit_code == 2, result.output
        assert fragment in result.stderr
        assert result.stdout == ""
    result = CliRunner().invoke(app, ["simulate", str(config), "--set", "vibration.amplitude=-1"])
    assert result.exit_code == 2 and "vibration.amplitude" in result.stderr


def test_a_folder_without_the_counted_meshes_exits_2_saying_how_to_name_them(tmp_path):
    import trimesh

    scans = tmp_path / "scans"
    scans.mkdir()
    trimesh.creation.box((0.08, 0.04, 0.012)).export(scans / "remote.stl")
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)  # counts the built-in smartphone and camera
    result = CliRunner().invoke(app, ["simulate", str(config), "--set", f"items.folder={scans}"])
    assert result.exit_code == 2, result.output
    assert "counts.smartphone: no mesh smartphone" in result.stderr
    assert "counts = { remote = 1 }" in result.stderr  # the fix, in the folder's own stems
    result = CliRunner().invoke(
        app, ["simulate", str(config), "--set", f"items.folder={scans}", "--set", "items.counts={remote = 1}"]
    )
    assert result.exit_code == 2 and "masses.remote" in result.stderr
