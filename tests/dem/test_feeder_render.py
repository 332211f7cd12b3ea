"""Feeder pictures: snapshots written by SnapshotWriter read back unchanged, the PNG shows retained
items in their own colour, and the GIF has one image per frame."""

import numpy as np
import pytest
from PIL import Image

from dem import quaternion
from dem.scenarios.render import (
    GONE,
    IN_TRAY,
    RETAINED_COLOUR,
    SnapshotError,
    SnapshotWriter,
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


def test_gif_has_one_image_per_frame(two_item_run):
    path = render_gif(load_run(two_item_run), two_item_run / "run.gif")

    with Image.open(path) as gif:
        assert gif.n_frames == 3


def test_missing_scene_is_an_error_that_says_where_snapshots_come_from(tmp_path):
    with pytest.raises(SnapshotError, match="--snapshots"):
        load_run(tmp_path)
