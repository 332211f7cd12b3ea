"""``demcal render``: pictures of a feeder run from the snapshots ``demcal simulate --snapshots``
wrote: a PNG (top and side view) at chosen times and, optionally, an animated GIF.

It parses and reports; the drawing is ``dem.scenarios.render``.
"""

from __future__ import annotations

from pathlib import Path

import typer


def parse_times(text: str) -> list[float]:
    """``"0,5,30"`` as [0.0, 5.0, 30.0]; raises ``typer.BadParameter`` naming the bad entry."""
    times = []
    for part in text.split(","):
        try:
            times.append(float(part))
        except ValueError:
            raise typer.BadParameter(f"{part!r} is not a time in seconds; use e.g. --times 0,5,30") from None
    return times


def register(app: typer.Typer) -> None:
    @app.command("render")
    def render(
        snapshot_dir: Path = typer.Argument(..., exists=True, file_okay=False, help="From --snapshots."),
        times: str | None = typer.Option(
            None,
            "--times",
            help="Simulated seconds to draw, e.g. 0,5,30 (default: three moments with items in the tray).",
        ),
        out: Path | None = typer.Option(None, "--out", help="PNG to write (default SNAPSHOT_DIR/run.png)."),
        gif: Path | None = typer.Option(None, "--gif", help="Also write an animated GIF here."),
        fps: float = typer.Option(10.0, "--fps", min=0.5, max=50, help="GIF frames per second."),
    ) -> None:
        """Draw the tray and its items (retained ones in red) at chosen times, and a GIF of the run."""
        from dem.scenarios.render import SnapshotError, default_times, load_run, render_gif, render_png

        try:
            run = load_run(snapshot_dir)
        except SnapshotError as exc:
            typer.secho(f"error: {exc}", err=True, fg="red")
            raise typer.Exit(2) from None
        chosen = default_times(run) if times is None else parse_times(times)
        png = render_png(run, chosen, out or snapshot_dir / "run.png")
        typer.echo(f"wrote {png}")
        if gif is not None:
            typer.echo(f"wrote {render_gif(run, gif, fps=fps)}")
