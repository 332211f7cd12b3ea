"""``demcal simulate``: run one feeder simulation from a TOML config, with a progress bar and a
summary, or one JSON object for scripts.

It parses and reports; the simulation itself is ``dem.scenarios.feeder.run_feeder``.
"""

from __future__ import annotations

import json
import math
import sys
import time
import tomllib
from pathlib import Path

import typer

PARAMETER_NAMES = ("E", "nu", "e", "mu")


class SetError(ValueError):
    """A ``--set`` option cannot be applied; the message says which one and why."""


def _parse_value(text: str):
    """A TOML value (number, boolean, quoted string, array); a bare word is taken as a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def split_sets(sets: list[str]) -> tuple[dict[str, float], dict[str, object]]:
    """``--set`` options as contact parameters (E, nu, e, mu) and dotted config overrides."""
    params: dict[str, float] = {}
    overrides: dict[str, object] = {}
    for item in sets:
        key, sep, text = item.partition("=")
        key, text = key.strip(), text.strip()
        if not sep or not key or not text:
            raise SetError(f"--set {item!r}: expected KEY=VALUE, e.g. --set E=5e6")
        if key in PARAMETER_NAMES:
            try:
                value = float(text)
            except ValueError:
                raise SetError(f"--set {key}={text}: {key} must be a number") from None
            if not math.isfinite(value):
                raise SetError(f"--set {key}={text}: {key} must be finite")
            params[key] = value
        elif "." in key:
            overrides[key] = _parse_value(text)
        else:
            raise SetError(
                f"--set {key}: unknown key; use one of {', '.join(PARAMETER_NAMES)} or a dotted config "
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
        config_path: Path = typer.Argument(..., exists=True, dir_okay=False, help="Feeder config (TOML)."),
        sets: list[str] = typer.Option(
            [], "--set", help="E=5e6, nu=, e=, mu=, or a dotted config key (vibration.amplitude=2e-3)."
        ),
        seed: int = typer.Option(0, "--seed", help="Seed of item shapes, positions and orientations."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object and nothing else."),
        snapshots: Path | None = typer.Option(
            None, "--snapshots", help="Write snapshots for `demcal render`."
        ),
        vtk: Path | None = typer.Option(
            None, "--vtk", help="Write VTK files for ParaView (spheres and tray) into this folder."
        ),
        timeout: float | None = typer.Option(None, "--timeout", min=0, help="Give up after this many s."),
    ) -> None:
        """Run one vibration feeder simulation and report N_t, discharge times and cost."""
        from pydantic import ValidationError

        from dem.scenarios.feeder import FeederConfig, load_feeder_config, run_feeder

        try:
            params, overrides = split_sets(sets)
            config = load_feeder_config(config_path)
            if overrides:
                data = apply_overrides(config.model_dump(mode="json"), overrides)
                config = FeederConfig.model_validate(data)
        except SetError as exc:
            _fail(str(exc))
        except ValidationError as exc:
            _fail(f"{config_path}: {exc}")
        except (OSError, tomllib.TOMLDecodeError) as exc:
            _fail(f"{config_path}: {exc}")

        deadline = time.monotonic() + timeout if timeout is not None else None
        result = _run_with_progress(run_feeder, config, params, seed, deadline, snapshots, vtk, quiet=as_json)
        if as_json:
            keys = (
                "n_remaining", "n_items", "discharge_times", "emptied_at", "wall_time_s", "cost", "steps",
                "dt", "sim_time", "status", "message", "params", "seed", "version",
            )  # fmt: skip
            dumped = result.model_dump(mode="json")
            sys.stdout.write(json.dumps({key: dumped[key] for key in keys}) + "\n")
        else:
            _print_summary(result)
        if not result.ok:
            raise typer.Exit(1)


def _run_with_progress(run_feeder, config, params, seed, deadline, snapshots, vtk, quiet):
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    end = config.stages.end
    columns = (
        TextColumn("[bold]feeder"),
        BarColumn(),
        TextColumn("{task.completed:6.2f} / {task.total:.2f} s simulated"),
        TextColumn("{task.fields[left]} items left"),
        TimeElapsedColumn(),
    )
    console = Console(stderr=True)
    with Progress(*columns, console=console, disable=quiet, transient=False) as bar:
        task = bar.add_task("run", total=end, left="?")

        def progress(t: float, left: int) -> None:
            bar.update(task, completed=min(t, end), left=left)

        return run_feeder(
            config,
            params,
            seed,
            deadline=deadline,
            progress=progress,
            snapshot_dir=snapshots,
            vtk_dir=vtk,
        )


def _print_summary(result) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table("quantity", "value", title=f"feeder run: {result.status.value}")
    table.add_row("N_t (items left in the tray)", f"{result.n_remaining} of {result.n_items}")
    discharged = sorted(t for t in result.discharge_times if t is not None)
    if discharged:
        table.add_row("discharge times, s", f"first {discharged[0]:.2f}, last {discharged[-1]:.2f}")
    table.add_row("tray emptied at, s", "-" if result.emptied_at is None else f"{result.emptied_at:.2f}")
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
    Console().print(table)
