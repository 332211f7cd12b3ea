"""Running an external engine's program: in its folder, logged to a file, killed at the deadline
or on a stop request (both polled every ``POLL_S``), never left running."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

from dem.result import SimulationStatus
from dem.scenarios.base import RunControl

POLL_S = 0.1
SCREEN = "screen.txt"


def run_process(
    command: list[str], folder: Path, control: RunControl, env: dict[str, str] | None = None
) -> tuple[SimulationStatus, str]:
    """Run ``command`` in ``folder`` with output to ``folder/screen.txt`` and ``env`` added to the
    environment; (status, message)."""
    environment = {**os.environ, **(env or {})}
    with open(folder / SCREEN, "w") as screen:
        try:
            process = subprocess.Popen(
                command,
                cwd=folder,
                stdout=screen,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=environment,
            )
        except OSError as exc:
            return SimulationStatus.ERROR, f"could not start {command[0]!r}: {exc}"
        try:
            while process.poll() is None:
                if control.deadline is not None and time.monotonic() > control.deadline:
                    return SimulationStatus.TIMEOUT, f"deadline passed while {Path(command[0]).name} ran"
                if control.should_stop is not None and control.should_stop():
                    return SimulationStatus.CANCELLED, f"cancelled while {Path(command[0]).name} ran"
                time.sleep(POLL_S)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
    if process.returncode != 0:
        return (
            SimulationStatus.ERROR,
            f"{Path(command[0]).name} exited with {process.returncode}: {screen_tail(folder)}",
        )
    return SimulationStatus.OK, ""


def screen_tail(folder: Path, lines: int = 3) -> str:
    path = folder / SCREEN
    if not path.exists():
        return ""
    return " | ".join(path.read_text(errors="replace").strip().splitlines()[-lines:])
