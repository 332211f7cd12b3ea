"""The feeder tray: its parametric mesh has the paper's shape, faces items from the inside, tilts
as configured, and a user's STL in millimetres loads as the same tray."""

import math

import numpy as np
import pytest
from pydantic import ValidationError

from dem.scenarios.tray import TrayConfig, TrayMeshError, build_tray, parametric_tray_mesh


def _face_areas_and_normals(vertices, faces):
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    return area, cross / (2 * area[:, None])


def test_floor_area_is_rectangle_plus_trapezoid_plus_channel():
    config = TrayConfig()
    vertices, faces = parametric_tray_mesh(config)
    area, normal = _face_areas_and_normals(vertices, faces)

    floor = normal[:, 2] > 0.99
    expected = (
        config.inlet_width * config.inlet_length
        + 0.5 * (config.inlet_width + config.outlet_width) * config.taper_length
        + config.outlet_width * config.outlet_length
    )
    assert area[floor].sum() == pytest.approx(expected, rel=1e-12)


def test_wall_normals_point_into_the_tray_and_the_outlet_end_is_open():
    config = TrayConfig()
    vertices, faces = parametric_tray_mesh(config)
    _, normal = _face_areas_and_normals(vertices, faces)
    centroid = vertices[faces].mean(axis=1)

    walls = np.abs(normal[:, 2]) < 1e-9
    side = walls & (np.abs(normal[:, 1]) > 1e-9)
    assert np.all(normal[side, 1] * centroid[side, 1] < 0)  # a side wall's normal points to y = 0
    back = walls & (np.abs(normal[:, 1]) < 1e-9)
    assert np.allclose(centroid[back, 0], 0.0) and np.all(normal[back, 0] > 0.99)
    assert not np.any(np.all(np.isclose(vertices[faces][:, :, 0], config.length), axis=1))
    assert vertices[:, 2].max() == pytest.approx(config.wall_height)


def test_taper_wall_reaches_the_outlet_width():
    config = TrayConfig(taper_length=0.2, outlet_length=0.0)
    vertices, _ = parametric_tray_mesh(config)

    at_outlet = np.isclose(vertices[:, 0], config.length)
    assert np.abs(vertices[at_outlet, 1]).max() == pytest.approx(config.outlet_width / 2)


def test_tilt_lowers_the_outlet_end_by_length_times_sine():
    config = TrayConfig(tilt_deg=5.0)
    tray = build_tray(config)

    outlet_floor = tray.to_world(np.array([[config.length, 0.0, 0.0]]))[0]
    assert outlet_floor[2] == pytest.approx(-config.length * math.sin(math.radians(5.0)), rel=1e-12)
    assert tray.to_tray_frame(tray.vertices) == pytest.approx(parametric_tray_mesh(config)[0])


def test_user_stl_in_millimetres_loads_as_the_same_tray(tmp_path):
    import trimesh

    config = TrayConfig()
    vertices, faces = parametric_tray_mesh(config)
    path = tmp_path / "tray.stl"
    trimesh.Trimesh(vertices * 1000.0, faces, process=False).export(path)

    tray = build_tray(TrayConfig(mesh_file=path, mesh_scale=0.001))

    assert tray.outlet_x == pytest.approx(config.length)
    assert tray.wall_height == pytest.approx(config.wall_height)
    assert tray.inlet_area == pytest.approx(config.inlet_width * config.inlet_length)


def test_user_stl_in_wrong_units_names_mesh_scale(tmp_path):
    import trimesh

    vertices, faces = parametric_tray_mesh(TrayConfig())
    path = tmp_path / "tray.stl"
    trimesh.Trimesh(vertices * 1000.0, faces, process=False).export(path)

    with pytest.raises(TrayMeshError, match="mesh_scale"):
        build_tray(TrayConfig(mesh_file=path))


def test_outlet_wider_than_inlet_is_an_error_naming_outlet_width():
    with pytest.raises(ValidationError, match="outlet_width"):
        TrayConfig(inlet_width=0.1, outlet_width=0.2)
