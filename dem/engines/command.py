r"""The command engine: run a scenario with any program (Yade, EDEM, Rocky, a script of your own).

A study selects it with ``engine = "command"`` and ``[engine_options]``::

    [engine_options]
    template = "heap.py.in"          # input template, relative to the study file
    input_name = "heap.py"           # the rendered input's file name (default: template's name
                                     # without ".in")
    command = ["yade", "-n", "-x", "$input"]
    # responses: the program writes responses.json into its working folder, e.g.
    #   {"angle_deg": 31.5, "height": 0.05, "sim_time": 2.0}
    # or give one regular expression per response, matched on its screen output (group 1):
    # patterns = { angle_deg = "angle of repose: ([-0-9.eE+]+)" }

The template and every command argument are rendered with Python's ``string.Template``:
``$E $nu $e $mu`` (the trial's parameters; the item-wall ones of ``dem/parameters.py``,
``$E_wall`` ..., too when the study or the scenario's ``[params]`` names them), ``$seed``,
``$input`` (the input file's name),
``$config_json`` (the scenario's whole config as JSON) and every config value by its dotted key
with underscores (``$particles_count``, ``$cylinder_lift_speed``). The program runs in a fresh
temporary folder with the deadline and stop requests of any run; a non-zero exit, a missing
response or a value that is not a number is a failed run with a message. Every declared response
of the scenario must be produced; ``sim_time`` and ``cost`` are optional extras.
"""

from __future__ import annotations

import json
import math
import re
import string
import tempfile
import time
from pathlib import Path
from typing import Any

from dem.engines.process import SCREEN, run_process
from dem.parameters import ALL_PARAMETER_NAMES
from dem.result import SimulationResult, SimulationStatus
from dem.scenarios.base import RunControl, Scenario, merged_params

RESPONSES_FILE = "responses.json"


def flatten(data: Any, prefix: str = "") -> dict[str, str]:
    """Config values by dotted key, with underscores: {"particles_count": "400", ...}."""
    out: dict[str, str] = {}
    if isinstance(data, dict):
        for key, value in data.items():
            out.update(flatten(value, f"{prefix}_{key}" if prefix else str(key)))
    elif prefix:
        out[prefix] = json.dumps(data) if isinstance(data, list) else str(data)
    return out


class CommandEngine:
    name = "command"
    parameters = ALL_PARAMETER_NAMES  # the template places them

    def unavailable(self, options=None) -> str:
        return ""  # the program is the study's; a missing one fails its runs with a message

    def refuses(self, scenario: Scenario, config, options=None) -> str:
        options = options or {}
        if not options.get("command"):
            return "engine 'command' needs engine_options.command (a list: program and arguments)"
        if not (options.get("template") or options.get("template_text")):
            return "engine 'command' needs engine_options.template (an input template file)"
        template = options.get("template")
        if template and not Path(template).is_file():
            return f"engine_options.template: no such file {template}"
        return ""

    def run(self, scenario: Scenario, config, params, seed: int, control: RunControl, options=None):
        started = time.monotonic()
        options = options or {}
        checked, problem = merged_params(config.params, params)
        base = {"seed": seed, "params": checked, "engine": self.name}
        if problem:
            return SimulationResult(status=SimulationStatus.ERROR, message=problem, **base)
        text = options.get("template_text") or Path(options["template"]).read_text()
        template_name = Path(options.get("template") or "input.in").name
        input_name = options.get("input_name") or template_name.removesuffix(".in")
        values = {
            **flatten(config.model_dump(mode="json")),
            **{k: repr(float(v)) for k, v in checked.items()},
            "seed": str(seed),
            "input": input_name,
            "config_json": json.dumps(config.model_dump(mode="json")),
        }
        responses: dict[str, float | None] = {r.name: None for r in scenario.responses}
        extras: dict[str, float] = {}
        with tempfile.TemporaryDirectory(prefix="demcal-command-") as tmp:
            folder = Path(tmp)
            try:
                (folder / input_name).write_text(string.Template(text).substitute(values))
                command = [string.Template(str(arg)).substitute(values) for arg in options["command"]]
            except (KeyError, ValueError) as exc:
                message = f"engine_options: the template or command uses an unknown placeholder {exc}"
                return SimulationResult(status=SimulationStatus.ERROR, message=message, **base)
            status, message = run_process(command, folder, control)
            if status is SimulationStatus.OK:
                try:
                    found = _read_responses(folder, options.get("patterns"))
                    missing = [name for name in responses if name not in found]
                    if missing:
                        raise ValueError(f"the program did not report {', '.join(missing)}")
                    responses = {name: found[name] for name in responses}
                    extras = {k: found[k] for k in ("sim_time", "cost") if k in found}
                except (ValueError, OSError) as exc:
                    status, message = SimulationStatus.ERROR, f"could not read the responses: {exc}"
        return SimulationResult(
            status=status,
            message=message,
            responses=responses,
            sim_time=max(0.0, extras.get("sim_time", 0.0)),
            cost=max(0.0, extras.get("cost", 0.0)),
            wall_time_s=time.monotonic() - started,
            **base,
        )


def _read_responses(folder: Path, patterns: dict[str, str] | None) -> dict[str, float]:
    found: dict[str, float] = {}
    if patterns:
        screen = (folder / SCREEN).read_text(errors="replace")
        for name, pattern in patterns.items():
            matches = re.findall(pattern, screen)
            if matches:
                found[name] = _number(name, matches[-1] if isinstance(matches[-1], str) else matches[-1][0])
    path = folder / RESPONSES_FILE
    if path.exists():
        data = json.loads(path.read_text())
        if not isinstance(data, dict):
            raise ValueError(f"{RESPONSES_FILE} must hold an object of name: number")
        found.update({str(k): _number(k, v) for k, v in data.items()})
    elif not patterns:
        raise ValueError(f"the program wrote no {RESPONSES_FILE}")
    return found


def _number(name: str, value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r} is not a number") from None
    if not math.isfinite(number):
        raise ValueError(f"{name} = {value!r} is not finite")
    return number
