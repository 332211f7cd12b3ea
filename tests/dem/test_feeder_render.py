"""Feeder pictures: snapshots written by SnapshotWriter read back unchanged, the PNG shows retained
items in their own colour, and the GIF has one image per frame."""

import numpy as np
import pytest
from PIL import Image

from dem import quaternion
from dem.result import SimulationStatus
from dem.scenarios.feeder import run_feeder
from dem.scenarios.feeder_config import FeederConfig
from dem.scenarios.render import (
    GONE,
    IN_TRAY,
    KIND_COLOURS,
    NOT_CREATED,
    RETAINED_COLOUR,
    SnapshotError,
    SnapshotWriter,
    default_times,
    load_run,
    render_gif,
    render_png,
)
from dem.scenarios.tray import TrayConfig, build_tray


def _box(lx, ly, lz):
    return np.array(
        [[sx * lx / 2, sy * ly / 2, sz * lz / 2] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    )


@pytest.fixture
def two_item_run(tmp_path):
    """A tray with two phones: the first leaves at t = 1 s, the second stays (retained)."""
    tray = build_tray(TrayConfig())
    hulls = [_box(0.146, 0.071, 0.008), _box(0.146, 0.071, 0.008)]
    writer = SnapshotWriter(
        tmp_path, tray.vertices, tray.faces, ["a", "b"], ["smartphone", "smartphone"], hulls
    )
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (2, 1))
    for k, t in enumerate((0.0, 0.5, 1.0)):
        pos = np.array([[0.1 + 0.25 * t, 0.0, 0.01], [0.15, 0.06, 0.01]])
        state = np.array([IN_TRAY if k < 2 else GONE, IN_TRAY])
        writer.frame(t, pos, quat, state)
    writer.summary({"discharge_times": [1.0, None]})
    return tmp_path


def test_quaternion_matrices_turn_x_to_y_for_a_quarter_turn_about_z_as_to_matrix_does():
    half = np.pi / 4
    rotation = quaternion.matrices(np.array([[np.cos(half), 0.0, 0.0, np.sin(half)]]))[0]

    assert rotation @ np.array([1.0, 0.0, 0.0]) == pytest.approx([0.0, 1.0, 0.0])
    assert rotation == pytest.approx(quaternion.matrix([np.cos(half), 0.0, 0.0, np.sin(half)]))


def test_snapshots_read_back_with_retained_items(two_item_run):
    run = load_run(two_item_run)

    assert [f.t for f in run.frames] == [0.0, 0.5, 1.0]
    assert run.retained.tolist() == [False, True]
    assert run.frame_at(0.6).t == 0.5
    assert run.hulls[1] == pytest.approx(_box(0.146, 0.071, 0.008))


def test_png_marks_the_retained_item_in_red(two_item_run):
    run = load_run(two_item_run)

    path = render_png(run, [0.0, 1.0], two_item_run / "run.png")

    pixels = np.asarray(Image.open(path).convert("RGB")).reshape(-1, 3).astype(int)
    red = np.array([int(RETAINED_COLOUR[i : i + 2], 16) for i in (1, 3, 5)])
    # Retained items are drawn with alpha 0.85 over the tray: the red must dominate some pixels.
    assert np.any(np.abs(pixels - red).sum(axis=1) < 60)


@pytest.mark.parametrize("columns", [1, 3])
def test_png_draws_nothing_at_its_right_edge_where_the_oblique_views_z_labels_were_cut(two_item_run, columns):
    # docs/clogged-run.png cut the last column's z tick labels ("0.2" showed as "0.") at the edge.
    run = load_run(two_item_run)

    path = render_png(run, list(np.linspace(0.0, 1.0, columns)), two_item_run / "run.png")

    pixels = np.asarray(Image.open(path).convert("L")).astype(int)
    assert pixels[:, -6:].min() >= 250, "something is drawn across the right edge of the picture"


def _near(pixels: np.ndarray, colour: str) -> np.ndarray:
    rgb = np.array([int(colour[i : i + 2], 16) for i in (1, 3, 5)])
    return np.abs(pixels.reshape(-1, 3).astype(int) - rgb).sum(axis=1) < 40


def test_gif_has_one_image_per_frame_each_with_the_legend(two_item_run):
    path = render_gif(load_run(two_item_run), two_item_run / "run.gif")

    with Image.open(path) as gif:
        assert gif.n_frames == 3
        for k in range(gif.n_frames):
            gif.seek(k)
            pixels = np.asarray(gif.convert("RGB"))
            legend_band = pixels[int(0.94 * len(pixels)) :]  # below the plots: the legend only
            assert _near(legend_band, KIND_COLOURS[0]).any() and _near(legend_band, RETAINED_COLOUR).any()


def test_default_times_are_moments_with_items_in_the_tray(tmp_path):
    # Frame 0 before any item is created and a last frame after all have left, as a run that
    # stops when empty has: neither is a picture of the run.
    writer = SnapshotWriter(tmp_path, *_tray(), ["a", "b"], ["camera", "camera"], [_box(0.1, 0.06, 0.04)] * 2)
    states = [(NOT_CREATED, NOT_CREATED), (IN_TRAY, NOT_CREATED), (IN_TRAY, IN_TRAY), (IN_TRAY, IN_TRAY),
              (GONE, IN_TRAY), (GONE, IN_TRAY), (GONE, GONE)]  # fmt: skip
    for k, state in enumerate(states):
        writer.frame(0.5 * k, np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)), np.array(state))

    times = default_times(load_run(tmp_path))

    assert times == [1.0, 1.5, 2.5]
    run = load_run(tmp_path)
    assert all(np.any(run.frame_at(t).state == IN_TRAY) for t in times)


def _tray():
    tray = build_tray(TrayConfig())
    return tray.vertices, tray.faces


def test_a_feeder_run_records_its_tilt_vibration_and_the_trays_displacement(tmp_path):
    frequency, amplitude, angle, start = 7.0, 2e-3, 25.0, 0.2
    config = FeederConfig.model_validate(
        {
            "tray": {"tilt_deg": 4.0},
            "items": {"counts": {"camera": 1}, "spread": 0.0},
            "stages": {"insertion_time": 0.01, "vibration_start": start, "vibration_time": 0.15},
            "vibration": {"frequency": frequency, "amplitude": amplitude, "angle_deg": angle},
            "run": {"snapshot_interval": 0.013},
        }
    )  # fmt: skip

    result = run_feeder(config, {"E": 1e6, "mu": 0.5}, seed=0, snapshot_dir=tmp_path)

    assert result.status is SimulationStatus.OK, result.message
    run = load_run(tmp_path)
    assert run.tilt_deg == 4.0
    assert run.vibration.angle_deg == pytest.approx(angle)
    vibration = run.vibration
    assert (vibration.amplitude, vibration.frequency, vibration.start) == (amplitude, frequency, start)
    u = np.array([np.cos(np.radians(angle)), 0.0, np.sin(np.radians(angle))])
    for frame in run.frames:
        expected = amplitude * np.sin(2 * np.pi * frequency * max(frame.t - start, 0.0)) * u
        assert frame.tray_offset == pytest.approx(expected, abs=1e-9)
    assert max(np.linalg.norm(f.tray_offset) for f in run.frames) > 0.5 * amplitude
    # Every item's hull is drawn as a closed surface: its triangles cover each hull point.
    assert set(run.hull_faces[0].ravel()) == set(range(len(run.hulls[0])))


def test_snapshots_without_tilt_or_motion_read_as_a_level_still_tray(two_item_run):
    for path in [two_item_run / "scene.npz", *two_item_run.glob("frame_*.npz")]:
        with np.load(path) as data:
            kept = {k: data[k] for k in data.files if k not in ("tilt_deg", "vibration", "tray_offset")}
        np.savez_compressed(path, **kept)

    run = load_run(two_item_run)

    assert (run.tilt_deg, run.vibration) == (0.0, None)
    assert all(np.array_equal(f.tray_offset, np.zeros(3)) for f in run.frames)


def test_missing_scene_is_an_error_that_says_where_snapshots_come_from(tmp_path):
    with pytest.raises(SnapshotError, match="--snapshots"):
        load_run(tmp_path)
