"""Pictures of a feeder run that a person can look at: the snapshot files a run writes, and the
PNG (top and side view) and animated GIF made from them.

The snapshot directory (written by ``SnapshotWriter`` during ``run_feeder``):

- ``scene.npz``: ``tray_vertices`` (world frame, m), ``tray_faces``, and per item its
  ``item_names``, ``item_kinds`` and the convex hull of its mesh in the body's principal frame
  (``hull_points`` concatenated, ``hull_start`` the first row of each item, length n_items + 1).
- ``frame_NNNNNN.npz``: ``t`` (simulated s), ``pos`` (n_items, 3), ``quat`` (n_items, 4, scalar
  first, body to world), ``state`` (n_items,: 0 not yet created, 1 in the tray, 2 gone).
- ``summary.json``: the run's ``SimulationResult`` as JSON, written at the end. Items whose
  ``discharge_times`` entry is null stayed in the tray: the pictures mark them as retained.

This module draws; it never runs a simulation and never changes the files it reads.
"""

from __future__ import annotations

import io
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dem import quaternion

logger = logging.getLogger(__name__)

NOT_CREATED, IN_TRAY, GONE = 0, 1, 2
KIND_COLOURS = ("#4c72b0", "#55a868", "#8172b2", "#ccb974", "#64b5cd", "#937860")
RETAINED_COLOUR = "#d62728"


class SnapshotError(ValueError):
    """A snapshot directory is missing or incomplete; the message says which file."""


class SnapshotWriter:
    """Writes the scene once, then one frame per call, into a directory it creates."""

    def __init__(
        self,
        directory: Path,
        tray_vertices: np.ndarray,
        tray_faces: np.ndarray,
        names: Sequence[str],
        kinds: Sequence[str],
        hulls: Sequence[np.ndarray],
    ) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self._count = 0
        np.savez_compressed(
            self.directory / "scene.npz",
            tray_vertices=np.asarray(tray_vertices, dtype=float),
            tray_faces=np.asarray(tray_faces, dtype=np.int64),
            item_names=np.array(list(names), dtype=str),
            item_kinds=np.array(list(kinds), dtype=str),
            hull_points=np.concatenate([np.asarray(h, dtype=float) for h in hulls]),
            hull_start=np.cumsum([0] + [len(h) for h in hulls]),
        )

    def frame(self, t: float, pos: np.ndarray, quat: np.ndarray, state: np.ndarray) -> None:
        np.savez_compressed(
            self.directory / f"frame_{self._count:06d}.npz",
            t=float(t),
            pos=np.asarray(pos, dtype=float),
            quat=np.asarray(quat, dtype=float),
            state=np.asarray(state, dtype=np.int8),
        )
        self._count += 1

    def summary(self, result_json: dict) -> None:
        (self.directory / "summary.json").write_text(json.dumps(result_json, indent=2))


@dataclass(frozen=True)
class Frame:
    t: float
    pos: np.ndarray
    quat: np.ndarray
    state: np.ndarray


@dataclass(frozen=True)
class Run:
    """A snapshot directory, read back."""

    tray_vertices: np.ndarray
    tray_faces: np.ndarray
    names: list[str]
    kinds: list[str]
    hulls: list[np.ndarray]
    frames: list[Frame]
    retained: np.ndarray  # (n_items,) bool: stayed in the tray to the end (False if unknown)

    def frame_at(self, t: float) -> Frame:
        """The frame closest to simulated time ``t``."""
        times = np.array([f.t for f in self.frames])
        return self.frames[int(np.argmin(np.abs(times - t)))]


def load_run(directory: Path) -> Run:
    directory = Path(directory)
    scene_path = directory / "scene.npz"
    if not scene_path.is_file():
        raise SnapshotError(f"{directory} has no scene.npz; pass a directory written by --snapshots")
    frame_paths = sorted(directory.glob("frame_*.npz"))
    if not frame_paths:
        raise SnapshotError(f"{directory} has no frame_*.npz files; the run wrote no snapshot")
    with np.load(scene_path) as scene:
        start = scene["hull_start"]
        points = scene["hull_points"]
        hulls = [points[start[i] : start[i + 1]] for i in range(len(start) - 1)]
        names = [str(n) for n in scene["item_names"]]
        kinds = [str(k) for k in scene["item_kinds"]]
        tray_vertices, tray_faces = scene["tray_vertices"], scene["tray_faces"]
    frames = []
    for path in frame_paths:
        with np.load(path) as data:
            frames.append(Frame(float(data["t"]), data["pos"], data["quat"], data["state"]))
    retained = np.zeros(len(names), dtype=bool)
    summary_path = directory / "summary.json"
    if summary_path.is_file():
        times = json.loads(summary_path.read_text()).get("discharge_times", [])
        if len(times) == len(names):
            retained = np.array([t is None for t in times])
    else:
        logger.warning(
            "%s has no summary.json (the run did not finish); no item is marked retained", directory
        )
    return Run(tray_vertices, tray_faces, names, kinds, hulls, frames, retained)


def _outline(points_2d: np.ndarray) -> np.ndarray:
    """Convex outline of projected points, as a closed polygon."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points_2d)
    except QhullError:  # an edge-on flat item projects to a line: draw its extent
        return points_2d[[np.argmin(points_2d[:, 0]), np.argmax(points_2d[:, 0])]]
    return points_2d[hull.vertices]


def draw_frame(run: Run, frame: Frame, axes_top, axes_side) -> None:
    """Tray and items of one frame on two matplotlib axes (top: x-y, side: x-z)."""
    from matplotlib.patches import Polygon

    kind_names = sorted(set(run.kinds))
    tri = run.tray_vertices[run.tray_faces]
    for ax, (i, j) in ((axes_top, (0, 1)), (axes_side, (0, 2))):
        for face in tri:
            ax.add_patch(Polygon(face[:, [i, j]], closed=True, fc="#dddddd", ec="none", zorder=0))
    rotations = quaternion.matrices(frame.quat)
    # Draw from the bottom up so that the top view shows what a camera above would see.
    order = np.argsort(frame.pos[:, 2])
    for k in order:
        if frame.state[k] != IN_TRAY:
            continue
        world = frame.pos[k] + run.hulls[k] @ rotations[k].T
        colour = RETAINED_COLOUR if run.retained[k] else KIND_COLOURS[kind_names.index(run.kinds[k]) % 6]
        for ax, (i, j) in ((axes_top, (0, 1)), (axes_side, (0, 2))):
            ax.add_patch(
                Polygon(_outline(world[:, [i, j]]), closed=True, fc=colour, ec="black", lw=0.5, alpha=0.85)
            )
    lo = run.tray_vertices.min(axis=0) - 0.05
    hi = run.tray_vertices.max(axis=0) + np.array([0.15, 0.05, 0.25])
    axes_top.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), aspect="equal", ylabel="y (m)")
    axes_side.set(
        xlim=(lo[0], hi[0]), ylim=(lo[2] - 0.1, hi[2]), aspect="equal", xlabel="x (m)", ylabel="z (m)"
    )
    in_tray = int(np.sum(frame.state == IN_TRAY))
    axes_top.set_title(f"t = {frame.t:.2f} s   items in view: {in_tray}", fontsize=9)


def _legend(run: Run, fig) -> None:
    from matplotlib.patches import Patch

    kind_names = sorted(set(run.kinds))
    handles = [Patch(fc=KIND_COLOURS[i % 6], ec="black", label=k) for i, k in enumerate(kind_names)]
    if run.retained.any():
        handles.append(Patch(fc=RETAINED_COLOUR, ec="black", label="retained at the end"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)


def render_png(run: Run, times: Sequence[float], path: Path, dpi: int = 110) -> Path:
    """One PNG with a column per requested time: top view above, side view below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        2,
        len(times),
        figsize=(4.2 * len(times), 5.4),
        squeeze=False,
        gridspec_kw={"height_ratios": [1.0, 0.8]},
    )
    for col, t in enumerate(times):
        draw_frame(run, run.frame_at(t), axes[0][col], axes[1][col])
    _legend(run, fig)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def render_gif(run: Run, path: Path, fps: float = 10.0, max_frames: int = 200, dpi: int = 70) -> Path:
    """An animated GIF of the run (top and side view), at most ``max_frames`` evenly spaced frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    step = max(1, int(np.ceil(len(run.frames) / max_frames)))
    images = []
    for frame in run.frames[::step]:
        fig, (top, side) = plt.subplots(2, 1, figsize=(5.0, 5.6), gridspec_kw={"height_ratios": [1.0, 0.8]})
        draw_frame(run, frame, top, side)
        fig.tight_layout()
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=dpi)
        plt.close(fig)
        buffer.seek(0)
        images.append(Image.open(buffer).convert("P", palette=Image.Palette.ADAPTIVE))
    path = Path(path)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path
