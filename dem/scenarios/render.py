"""Pictures of a feeder run that a person can look at: the snapshot files a run writes, and the
PNG (top view and an oblique side view) and animated GIF made from them.

The snapshot directory (written by ``SnapshotWriter`` during ``run_feeder``):

- ``scene.npz``: ``tray_vertices`` (world frame at rest, m), ``tray_faces``, ``tilt_deg`` and the
  tray's vibration (``vibration``: direction x, y, z, peak amplitude m, frequency Hz, start s), and
  per item its ``item_names``, ``item_kinds`` and the convex hull of its mesh in the body's
  principal frame (``hull_points`` concatenated, ``hull_start`` the first row of each item, length
  n_items + 1). Snapshots written before tilt and vibration were recorded read as 0 and none.
- ``frame_NNNNNN.npz``: ``t`` (simulated s), ``pos`` (n_items, 3), ``quat`` (n_items, 4, scalar
  first, body to world), ``state`` (n_items,: 0 not yet created, 1 in the tray, 2 gone) and
  ``tray_offset`` (3,: the tray's displacement by its motion at t, m; 0 if not recorded).
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
        tilt_deg: float = 0.0,
        vibration: Sequence[float] = (),
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
            tilt_deg=float(tilt_deg),
            vibration=np.asarray(vibration, dtype=float),
        )

    def frame(
        self, t: float, pos: np.ndarray, quat: np.ndarray, state: np.ndarray, tray_offset=(0.0, 0.0, 0.0)
    ) -> None:
        np.savez_compressed(
            self.directory / f"frame_{self._count:06d}.npz",
            t=float(t),
            pos=np.asarray(pos, dtype=float),
            quat=np.asarray(quat, dtype=float),
            state=np.asarray(state, dtype=np.int8),
            tray_offset=np.asarray(tray_offset, dtype=float),
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
    tray_offset: np.ndarray  # (3,) the tray's displacement by its motion, m


@dataclass(frozen=True)
class Vibration:
    """The tray's motion: peak ``amplitude`` (m) at ``frequency`` (Hz) along ``direction``."""

    direction: tuple[float, float, float]
    amplitude: float
    frequency: float
    start: float

    @property
    def angle_deg(self) -> float:
        """Inclination of the direction from the horizontal."""
        x, y, z = self.direction
        return float(np.degrees(np.arctan2(z, np.hypot(x, y))))


@dataclass(frozen=True)
class Run:
    """A snapshot directory, read back."""

    tray_vertices: np.ndarray
    tray_faces: np.ndarray
    names: list[str]
    kinds: list[str]
    hulls: list[np.ndarray]
    hull_faces: list[np.ndarray]  # per item, triangles of its hull (rows into hulls[i])
    frames: list[Frame]
    retained: np.ndarray  # (n_items,) bool: stayed in the tray to the end (False if unknown)
    tilt_deg: float = 0.0
    vibration: Vibration | None = None

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
        tilt_deg = float(scene["tilt_deg"]) if "tilt_deg" in scene else 0.0
        row = scene["vibration"] if "vibration" in scene else np.zeros(0)
    vibration = None
    if len(row):
        vibration = Vibration(tuple(float(v) for v in row[:3]), *(float(v) for v in row[3:6]))
    frames = []
    for path in frame_paths:
        with np.load(path) as data:
            offset = data["tray_offset"] if "tray_offset" in data else np.zeros(3)
            frames.append(Frame(float(data["t"]), data["pos"], data["quat"], data["state"], offset))
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
    hull_faces = [hull_triangles(h) for h in hulls]
    return Run(
        tray_vertices, tray_faces, names, kinds, hulls, hull_faces, frames, retained, tilt_deg, vibration
    )


def hull_triangles(points: np.ndarray) -> np.ndarray:
    """The triangles of the convex hull of ``points`` (rows into ``points``), outward-facing."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
    except QhullError:  # a degenerate (flat) hull: fan its points, enough to draw it
        return np.array([[0, k, k + 1] for k in range(1, len(points) - 1)], dtype=np.int64)
    faces = hull.simplices.copy()
    normals = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    inward = np.einsum("ij,ij->i", normals, points[faces[:, 0]] - points.mean(axis=0)) < 0
    faces[inward] = faces[inward][:, ::-1]
    return faces


def default_times(run: Run) -> list[float]:
    """Three moments that show items: the first frame with the most items in the tray, the last
    frame with any (the end, when some stayed), and halfway between them by frame."""
    counts = np.array([np.sum(f.state == IN_TRAY) for f in run.frames])
    if not counts.any():
        return [run.frames[0].t, run.frames[len(run.frames) // 2].t, run.frames[-1].t]
    first = int(np.argmax(counts))
    last = int(np.flatnonzero(counts)[-1])
    return [run.frames[k].t for k in (first, (first + last) // 2, last)]


def _outline(points_2d: np.ndarray) -> np.ndarray:
    """Convex outline of projected points, as a closed polygon."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points_2d)
    except QhullError:  # an edge-on flat item projects to a line: draw its extent
        return points_2d[[np.argmin(points_2d[:, 0]), np.argmax(points_2d[:, 0])]]
    return points_2d[hull.vertices]


def _item_colour(run: Run, k: int) -> str:
    kind_names = sorted(set(run.kinds))
    return RETAINED_COLOUR if run.retained[k] else KIND_COLOURS[kind_names.index(run.kinds[k]) % 6]


def _view_limits(run: Run) -> tuple[np.ndarray, np.ndarray]:
    """Tray bounds with room above it and beyond the outlet, where items are in view."""
    lo = run.tray_vertices.min(axis=0) - np.array([0.05, 0.05, 0.05])
    hi = run.tray_vertices.max(axis=0) + np.array([0.15, 0.05, 0.10])
    return lo, hi


def draw_frame(run: Run, frame: Frame, axes_top, axes_side) -> None:
    """Tray and items of one frame: a top view (x-y) on ``axes_top`` and an oblique view from the
    front on the 3D ``axes_side``, where the taper, the tilt and the direction of the tray's
    vibration can be seen."""
    from matplotlib.colors import to_rgba
    from matplotlib.patches import Polygon
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    tray = (run.tray_vertices + frame.tray_offset)[run.tray_faces]
    for face in tray:
        axes_top.add_patch(Polygon(face[:, :2], closed=True, fc="#dddddd", ec="#c8c8c8", lw=0.3, zorder=0))
    rotations = quaternion.matrices(frame.quat)
    # The tray is nearly transparent in the oblique view so that its front wall hides no item.
    polygons = list(tray)
    colours, edges = [to_rgba("#bdbdbd", 0.18)] * len(tray), [to_rgba("#6e6e6e", 0.6)] * len(tray)
    # Draw from the bottom up so that the top view shows what a camera above would see.
    for k in np.argsort(frame.pos[:, 2]):
        if frame.state[k] != IN_TRAY:
            continue
        world = frame.pos[k] + run.hulls[k] @ rotations[k].T
        colour = _item_colour(run, k)
        axes_top.add_patch(
            Polygon(_outline(world[:, :2]), closed=True, fc=colour, ec="black", lw=0.5, alpha=0.85)
        )
        faces = world[run.hull_faces[k]]
        polygons += list(faces)
        colours += [to_rgba(colour, 0.95)] * len(faces)
        edges += [to_rgba("black", 0.12)] * len(faces)
    axes_side.add_collection3d(
        Poly3DCollection(polygons, facecolors=colours, edgecolors=edges, linewidths=0.3)
    )
    lo, hi = _view_limits(run)
    axes_top.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), aspect="equal", xlabel="x (m)", ylabel="y (m)")
    axes_side.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]))
    axes_side.set_box_aspect(hi - lo, zoom=1.3)
    axes_side.view_init(elev=14, azim=-58)
    axes_side.grid(False)
    axes_side.tick_params(labelsize=6, pad=0)
    for axis in (axes_side.xaxis, axes_side.yaxis, axes_side.zaxis):
        axis.pane.set_visible(False)
    axes_side.set_xlabel("x (m)", fontsize=7, labelpad=-4)
    axes_side.set_zlabel("z (m)", fontsize=7, labelpad=-7)
    axes_side.zaxis.set_label_position("upper")  # beside its tick labels, at the right
    axes_side.zaxis.set_ticks_position("upper")
    _annotate_motion(run, axes_side, lo, hi)
    in_tray = int(np.sum(frame.state == IN_TRAY))
    axes_top.set_title(f"t = {frame.t:.2f} s   items in the tray: {in_tray}", fontsize=9)


def _annotate_motion(run: Run, axes, lo: np.ndarray, hi: np.ndarray) -> None:
    """The vibration direction as an arrow above the back of the tray, and the tilt in words."""
    words = f"tilt {run.tilt_deg:g} deg"
    if run.vibration is not None:
        v = run.vibration
        start = np.array([lo[0] + 0.05, lo[1] + 0.05, hi[2] - 0.06])
        arrow = 0.12 * np.asarray(v.direction)
        axes.quiver(*start, *arrow, color="#d55e00", lw=1.5, arrow_length_ratio=0.3)
        motion = f"{v.angle_deg:.0f} deg, {v.amplitude * 1e3:g} mm, {v.frequency:g} Hz"
        words = f"vibration (arrow) {motion}; {words}"
    axes.text2D(0.0, 0.98, words, transform=axes.transAxes, fontsize=7, va="top")


def _legend(run: Run, fig) -> None:
    from matplotlib.patches import Patch

    kind_names = sorted(set(run.kinds))
    handles = [Patch(fc=KIND_COLOURS[i % 6], ec="black", label=k) for i, k in enumerate(kind_names)]
    if run.retained.any():
        handles.append(Patch(fc=RETAINED_COLOUR, ec="black", label="retained at the end"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)


def _figure(columns: int, width: float, height: float):
    """A figure with a top view above an oblique view in each of ``columns`` columns."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(width * columns, height))
    # The oblique view's z tick labels and label stand out right of its axes (zoomed box): a right
    # margin of an inch and the space between columns leave room for them.
    right = 1.0 - 1.0 / (width * columns)
    grid = fig.add_gridspec(2, columns, height_ratios=[1.0, 1.1], left=0.08, right=right, top=0.95,
                            bottom=0.06, wspace=0.45)
    pairs = [
        (fig.add_subplot(grid[0, col]), fig.add_subplot(grid[1, col], projection="3d"))
        for col in range(columns)
    ]
    return fig, pairs


def render_png(run: Run, times: Sequence[float], path: Path, dpi: int = 110) -> Path:
    """One PNG with a column per requested time: top view above, oblique view below."""
    import matplotlib.pyplot as plt

    fig, pairs = _figure(len(times), 4.4, 6.6)
    for (top, side), t in zip(pairs, times, strict=True):
        draw_frame(run, run.frame_at(t), top, side)
    _legend(run, fig)
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def render_gif(run: Run, path: Path, fps: float = 10.0, max_frames: int = 200, dpi: int = 70) -> Path:
    """An animated GIF of the run (top and oblique view, with the legend), at most ``max_frames``
    evenly spaced frames."""
    import matplotlib.pyplot as plt
    from PIL import Image

    step = max(1, int(np.ceil(len(run.frames) / max_frames)))
    images = []
    for frame in run.frames[::step]:
        fig, [(top, side)] = _figure(1, 6.0, 7.4)
        draw_frame(run, frame, top, side)
        _legend(run, fig)
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=dpi)
        plt.close(fig)
        buffer.seek(0)
        images.append(Image.open(buffer).convert("P", palette=Image.Palette.ADAPTIVE))
    path = Path(path)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path
