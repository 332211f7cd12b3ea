"""``demcal simulate``: run one simulation of any scenario from a TOML config (its ``kind``
picks the scenario, ``--engine`` the engine), with a progress bar and a summary, or one JSON
object (the whole ``SimulationResult``) for scripts.

It parses and reports; the run itself is ``dem.engines.base.run_scenario``.
"""

from __future__ import annotations

import json
import sys
import time
import tomllib
from pathlib import Path

import typer

from api.commands.console import cli_console
from dem.parameters import ALL_PARAMETER_NAMES, range_problem


class SetError(ValueError):
    """A ``--set`` option cannot be applied; the message says which one and why."""


def _parse_value(text: str):
    """A TOML value (number, boolean, quoted string, array); a bare word is taken as a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def split_sets(sets: list[str]) -> tuple[dict[str, float], dict[str, object]]:
    """``--set`` options as contact parameters (``ALL_PARAMETER_NAMES``) and dotted config
    overrides."""
    params: dict[str, float] = {}
    overrides: dict[str, object] = {}
    for item in sets:
        key, sep, text = item.partition("=")
        key, text = key.strip(), text.strip()
        if not sep or not key or not text:
            raise SetError(f"--set {item!r}: expected KEY=VALUE, e.g. --set E=5e6")
        if key in ALL_PARAMETER_NAMES:
            try:
                value = float(text)
            except ValueError:
                raise SetError(f"--set {key}={text}: {key} must be a number") from None
            problem = range_problem(key, value)
            if problem is not None:
                raise SetError(f"--set {key}={text}: {problem}")
            params[key] = value
        elif "." in key:
            overrides[key] = _parse_value(text)
        else:
            raise SetError(
                f"--set {key}: unknown key; use one of {', '.join(ALL_PARAMETER_NAMES)} or a dotted config "
                "key such as vibration.amplitude"
            )
    return params, overrides


def apply_overrides(data: dict, overrides: dict[str, object]) -> dict:
    """The config as a dict with dotted keys set (validation happens afterwards)."""
    for dotted, value in overrides.items():
        node = data
        *parents, leaf = dotted.split(".")
        for part in parents:
            child = node.get(part)
            if not isinstance(child, dict):
                raise SetError(f"--set {dotted}: {part!r} is not a section of the config")
            node = child
        node[leaf] = value
    return data


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", err=True, fg="red")
    raise typer.Exit(2)


def register(app: typer.Typer) -> None:
    @app.command("simulate")
    def simulate(
        config_path: Path = typer.Argument(
            ..., exists=True, dir_okay=False, help="Scenario config (TOML; kind = ... picks the scenario)."
        ),
        sets: list[str] = typer.Option(
            [], "--set", help="E=5e6, nu=, e=, mu=, or a dotted config key (vibration.amplitude=2e-3)."
        ),
        seed: int = typer.Option(0, "--seed", help="Seed of shapes, positions and orientations."),
        engine: str = typer.Option("numba", "--engine", help="numba (built in) or liggghts."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object and nothing else."),
        snapshots: Path | None = typer.Option(
            None, "--snapshots", help="Write snapshots for `demcal render` (feeder)."
        ),
        vtk: Path | None = typer.Option(
            None, "--vtk", help="Write VTK XML frames and their .pvd time series (ParaView) here."
        ),
        timeout: float | None = typer.Option(None, "--timeout", min=0, help="Give up after this many s."),
    ) -> None:
        """Run one simulation and report its responses, time and cost."""
        from pydantic import ValidationError

        from dem.scenarios import registry
        from dem.scenarios.paths import READ_FILES

        try:
            params, overrides = split_sets(sets)
            config = registry.load_config_file(config_path)
            scenario = registry.get(config.kind)
            if overrides:
                data = apply_overrides(config.model_dump(mode="json"), overrides)
                config = scenario.config(data, context=READ_FILES)  # the user's own files
        except SetError as exc:
            _fail(str(exc))
        except registry.UnknownScenarioError as exc:
            _fail(f"{config_path}: kind: {exc}")
        except ValidationError as exc:
            _fail(f"{config_path}: {exc}")
        except (OSError, tomllib.TOMLDecodeError) as exc:
            _fail(f"{config_path}: {exc}")

        from dem.engines.base import UnknownEngineError, get_engine

        try:
            get_engine(engine)
        except UnknownEngineError as exc:
            _fail(f"--engine: {exc}")
        deadline = time.monotonic() + timeout if timeout is not None else None
        result = _run_with_progress(scenario, config, engine, params, seed, deadline, snapshots, vtk, as_json)
        if as_json:
            sys.stdout.write(json.dumps(result.model_dump(mode="json")) + "\n")
        else:
            _print_summary(scenario, result)
        if not result.ok:
            raise typer.Exit(1)


def _run_with_progress(scenario, config, engine, params, seed, deadline, snapshots, vtk, quiet):
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from dem.engines.base import run_scenario
    from dem.scenarios.base import RunControl

    end = scenario.duration(config) or 1.0
    columns = (
        TextColumn(f"[bold]{scenario.kind}"),
        BarColumn(),
        TextColumn("{task.completed:6.2f} / {task.total:.2f} s simulated"),
        TextColumn("{task.fields[count]} " + scenario.progress_label),
        TimeElapsedColumn(),
    )
    console = cli_console(stderr=True)
    with Progress(*columns, console=console, disable=quiet, transient=False) as bar:
        task = bar.add_task("run", total=end, count="?")

        def progress(t: float, count: int) -> None:
            bar.update(task, completed=min(t, end), count=count)

        control = RunControl(deadline=deadline, progress=progress, snapshot_dir=snapshots, vtk_dir=vtk)
        return run_scenario(scenario, config, params, seed, control, engine=engine)


def _print_summary(scenario, result) -> None:
    from rich.table import Table

    table = Table("quantity", "value", title=f"{scenario.kind} run ({result.engine}): {result.status.value}")
    for response in scenario.responses:
        value = result.responses.get(response.name)
        shown = "-" if value is None else (f"{int(value)}" if response.integer else f"{value:.4g}")
        unit = "" if response.unit == "1" else f" {response.unit}"
        table.add_row(f"{response.name} ({response.description.rstrip('.')})", f"{shown}{unit}")
    table.add_row("bodies", f"{result.n_items}")
    discharged = sorted(t for t in result.discharge_times if t is not None)
    if discharged:
        table.add_row("discharge times, s", f"first {discharged[0]:.2f}, last {discharged[-1]:.2f}")
    if result.emptied_at is not None:
        table.add_row("emptied at, s", f"{result.emptied_at:.2f}")
    table.add_row("simulated time, s", f"{result.sim_time:.3f}")
    table.add_row("wall time T, s", f"{result.wall_time_s:.1f}")
    table.add_row("steps / time step", f"{result.steps} / {result.dt:.3g} s")
    if result.steps:
        table.add_row("us per step", f"{1e6 * result.wall_time_s / result.steps:.1f}")
    table.add_row("cost", f"{result.cost:.4g}")
    table.add_row("params", ", ".join(f"{k}={v:g}" for k, v in result.params.items()))
    table.add_row("seed / version", f"{result.seed} / {result.version}")
    if result.message:
        table.add_row("message", result.message)
    cli_console().print(table)
