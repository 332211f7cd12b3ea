"""The feeder's item catalogue (issue 4, items): cited sizes and masses, per-item spread, the
camera's lens barrel, clumps consistent with each item's mesh, user meshes from a folder."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from dem.clumping import signed_distance
from dem.polyhedra import CORE_TOLERANCE, surface_gap
from dem.scenarios.items import (
    _CORNER_SECTIONS,
    CATALOGUE,
    FOLDER_MESH_FACES,
    KINDS,
    ItemsError,
    default_items,
    items_from_folder,
    nominal_volume,
)

SPREAD = 0.03

# The manufacturers' published figures the catalogue cites (``dem/scenarios/items.py``), as
# length x width x depth (mm) and mass (g), transcribed here independently of the catalogue.
PRODUCTS = {
    "smartphone": {
        "Apple iPhone 6": (138.1, 67.0, 6.9, 129),
        "Samsung Galaxy S7": (142.4, 69.6, 7.9, 152),
        "Samsung Galaxy S8": (148.9, 68.1, 8.0, 155),
        "Apple iPhone 11 Pro": (144.0, 71.4, 8.1, 188),
    },
    "feature_phone": {
        "Nokia 105 (2017)": (112.0, 49.0, 14.0, 73),
        "Nokia 3310 (2000)": (113.0, 48.0, 22.0, 133),
        "Motorola RAZR V3 (closed)": (98.0, 53.0, 13.9, 95),
    },
    "camera": {
        "Canon IXUS 160": (95.2, 54.3, 22.1, 127),
        "Canon IXUS 285 HS": (99.6, 58.0, 22.8, 147),
        "Sony Cyber-shot DSC-W800": (96.8, 55.5, 20.8, 125),
    },
}
KEYS = ("length", "width", "thickness", "mass")
TO_SI = (1e-3, 1e-3, 1e-3, 1e-3)  # mm -> m, g -> kg


def product_range(kind: str, key: str) -> tuple[float, float]:
    """(smallest, largest) of one dimension or the mass over the cited products, SI units."""
    index = KEYS.index(key)
    values = [figures[index] * TO_SI[index] for figures in PRODUCTS[kind].values()]
    return min(values), max(values)


@pytest.fixture(scope="module")
def items(tmp_path_factory):
    cache = tmp_path_factory.mktemp("clumps")
    return default_items(np.random.default_rng(42), spread=SPREAD, resolution=16, cache_dir=cache)


@pytest.mark.parametrize("kind", KINDS)
def test_nominal_items_lie_within_the_cited_product_data(kind):
    spec = CATALOGUE[kind]

    for key in KEYS:
        low, high = product_range(kind, key)
        assert low <= getattr(spec, key) <= high, f"{kind}.{key} outside the cited products"


def _polygon_area(radius: float, sections: int) -> float:
    """Area of the regular polygon trimesh builds for a circle (vertices on the circle)."""
    return 0.5 * sections * radius**2 * np.sin(2 * np.pi / sections)


@pytest.mark.parametrize("kind", KINDS)
def test_nominal_meshes_are_closed_with_the_spec_dimensions_and_analytic_volume(kind):
    spec = CATALOGUE[kind]

    mesh = spec.mesh()

    assert mesh.is_watertight
    expected_depth = spec.thickness + spec.lens_protrusion
    np.testing.assert_allclose(mesh.extents, [spec.length, spec.width, expected_depth], rtol=1e-6)
    # A slab whose outline is a rectangle with its corners rounded (corner circles drawn as
    # polygons of 4 x _CORNER_SECTIONS sides), plus the part of the lens barrel (a 32-gon prism)
    # standing above the body. The camera's boolean union (manifold3d) moves vertices by about
    # 1e-8 relative, hence rel=1e-6 rather than machine precision.
    r = spec.corner_radius
    outline = spec.length * spec.width - 4 * r**2 + _polygon_area(r, 4 * _CORNER_SECTIONS)
    barrel = _polygon_area(spec.lens_diameter / 2, 32) * spec.lens_protrusion
    assert nominal_volume(kind) == pytest.approx(outline * spec.thickness + barrel, rel=1e-6)


def test_camera_lens_barrel_makes_it_non_box():
    spec = CATALOGUE["camera"]

    mesh = spec.mesh()

    body = spec.length * spec.width * spec.thickness
    barrel = np.pi * (spec.lens_diameter / 2) ** 2 * spec.lens_protrusion
    assert mesh.volume < 0.8 * np.prod(mesh.extents)
    # Rounded corners take a little off the body; the barrel adds its own cylinder.
    assert mesh.volume == pytest.approx(body + barrel, rel=0.02)


def test_default_set_is_ten_of_each_kind_and_no_two_are_identical(items):
    kinds = [item.kind for item in items]
    masses = [item.mass for item in items]
    extents = {tuple(np.round(item.mesh.extents, 9)) for item in items}

    assert {kind: kinds.count(kind) for kind in KINDS} == dict.fromkeys(KINDS, 10)
    assert len({item.name for item in items}) == 30
    assert len(set(masses)) == 30
    assert len(extents) == 30


def test_spread_items_stay_within_the_cited_ranges_widened_by_the_spread(items):
    for item in items:
        spec = item.spec
        for key in KEYS:
            low, high = product_range(item.kind, key)
            value = getattr(spec, key)
            assert low * (1 - SPREAD) <= value <= high * (1 + SPREAD), f"{item.name}.{key}"
        assert item.mass == pytest.approx(spec.mass)
        depth = spec.thickness + spec.lens_protrusion
        np.testing.assert_allclose(item.mesh.extents, [spec.length, spec.width, depth], rtol=1e-6)


def test_each_item_clump_has_its_own_mesh_mass_properties_and_inscribed_spheres(items):
    for item in items[::7]:
        reference = item.mesh.copy()
        reference.density = item.mass / reference.volume

        clump = item.shape

        assert clump.mass == pytest.approx(item.mass)
        np.testing.assert_allclose(clump.com, reference.center_mass, atol=1e-12)
        tensor = clump.axes @ np.diag(clump.inertia) @ clump.axes.T
        np.testing.assert_allclose(tensor, reference.moment_inertia, rtol=1e-9, atol=1e-14)
        centres = clump.com + clump.offset @ clump.axes.T
        assert np.all(signed_distance(item.mesh, centres) >= clump.radius * (1 - 1e-5))
        assert clump.n_spheres <= 16
        assert 0 < clump.max_error < 0.5 * item.spec.width


def test_unknown_kind_is_an_error_listing_the_built_in_kinds():
    with pytest.raises(ItemsError, match="smartphone, feature_phone, camera"):
        default_items(np.random.default_rng(0), {"tablet": 2}, cache_dir=False)


def _write_folder(folder, scanned_faces: bool = False):
    box = trimesh.creation.box((80.0, 40.0, 12.0))  # millimetres
    box.export(folder / "remote.stl")
    blob = trimesh.creation.icosphere(subdivisions=5 if scanned_faces else 2, radius=20.0)
    blob.vertices *= [1.0, 0.8, 0.6]
    blob.export(folder / "scan.obj")
    manifest = {
        "scale": 0.001,
        "items": {"remote": {"count": 2, "mass": 0.09}, "scan": {"count": 1, "mass": 0.05}},
    }
    (folder / "items.json").write_text(json.dumps(manifest))


def test_items_from_a_folder_follow_the_manifest_and_decimate_scans(tmp_path):
    _write_folder(tmp_path, scanned_faces=True)

    loaded = items_from_folder(tmp_path, resolution=10, cache_dir=tmp_path / "cache")

    assert [item.kind for item in loaded] == ["remote", "remote", "scan"]
    assert [item.mass for item in loaded] == pytest.approx([0.09, 0.09, 0.05])
    np.testing.assert_allclose(sorted(loaded[0].mesh.extents), [0.012, 0.040, 0.080], rtol=1e-6)
    scan = loaded[2]
    assert len(scan.mesh.faces) <= FOLDER_MESH_FACES
    ellipsoid = 4.0 / 3.0 * np.pi * 0.020 * 0.016 * 0.012
    assert scan.mesh.volume == pytest.approx(ellipsoid, rel=0.02)
    assert scan.shape.mass == pytest.approx(0.05)


def test_folder_counts_and_masses_from_the_caller_override_the_manifest(tmp_path):
    _write_folder(tmp_path)

    loaded = items_from_folder(
        tmp_path, {"remote": 3}, {"remote": 0.1}, np.random.default_rng(1), 0.02, 8, cache_dir=False
    )

    assert len(loaded) == 3
    assert len({item.mass for item in loaded}) == 3
    assert all(0.098 <= item.mass <= 0.102 for item in loaded)


def test_folder_errors_name_the_missing_mesh_and_mass(tmp_path):
    _write_folder(tmp_path)

    with pytest.raises(ItemsError, match="counts.radio: no mesh radio"):
        items_from_folder(tmp_path, {"radio": 1}, {"radio": 0.1}, cache_dir=False)
    (tmp_path / "items.json").unlink()
    with pytest.raises(ItemsError, match="masses.remote"):
        items_from_folder(tmp_path, {"remote": 1}, {"scan": 0.1}, scale=0.001, cache_dir=False)
    with pytest.raises(ItemsError, match="no counts given and no items.toml"):
        items_from_folder(tmp_path, cache_dir=False)


@pytest.mark.parametrize("core_tolerance", [0.0, CORE_TOLERANCE])
def test_polyhedron_items_follow_their_meshes_within_the_edge_rounding(core_tolerance):
    items = default_items(
        np.random.default_rng(3),
        {"smartphone": 1, "camera": 1},
        representation="polyhedron",
        core_tolerance=core_tolerance,
    )
    phone, camera = items

    assert camera.shape.n_pieces == 2  # slab and lens barrel, the camera's known parts
    for item in items:
        reference = item.mesh.copy()
        reference.density = item.mass / reference.volume
        shape = item.shape
        assert shape.mass == pytest.approx(item.mass)
        np.testing.assert_allclose(shape.com, reference.center_mass, atol=1e-12)
        # Flat faces: the shape departs from the mesh only at rounded edges, r (sqrt(2) - 1) there,
        # and by at most core_tolerance r more where the simplified core lies inside the full one.
        largest, mean = surface_gap(shape, item.mesh, n_samples=1500)
        assert largest <= (0.5 + core_tolerance) * shape.rounding
        assert mean < 0.1 * shape.rounding
    assert phone.shape.rounding == pytest.approx(0.25 * phone.spec.thickness, rel=0.05)


def test_a_folder_mesh_becomes_convex_pieces_in_the_polyhedron_representation(tmp_path):
    a = trimesh.creation.box((60.0, 20.0, 20.0))
    b = trimesh.creation.box((20.0, 60.0, 20.0))
    b.apply_translation([20.0, 20.0, 0])
    trimesh.boolean.union([a, b], engine="manifold").export(tmp_path / "bracket.stl")
    (tmp_path / "items.json").write_text(
        json.dumps({"scale": 0.001, "items": {"bracket": {"count": 2, "mass": 0.1}}})
    )

    loaded = items_from_folder(tmp_path, representation="polyhedron")

    assert len(loaded) == 2
    assert loaded[0].shape.n_pieces >= 2
    assert loaded[0].shape.mass == pytest.approx(0.1)


def test_a_manifest_with_a_count_that_is_no_number_is_an_items_error(tmp_path):
    _write_folder(tmp_path)
    (tmp_path / "items.json").write_text(json.dumps({"items": {"remote": {"count": "two", "mass": 0.09}}}))

    with pytest.raises(ItemsError, match="scale are numbers"):
        items_from_folder(tmp_path, cache_dir=False)


def test_a_feeder_file_naming_a_folder_takes_its_counts_and_masses_from_the_manifest(tmp_path):
    from pydantic import ValidationError

    from dem.scenarios.feeder_config import FeederConfig, load_feeder_config

    (tmp_path / "scans").mkdir()
    _write_folder(tmp_path / "scans")
    (tmp_path / "feeder.toml").write_text('[items]\nfolder = "scans"\n')

    config = load_feeder_config(tmp_path / "feeder.toml")

    assert config.items.folder == tmp_path / "scans"  # relative to the file, not the working dir
    assert config.items.counts == {"remote": 2, "scan": 1}
    assert config.items.masses == {"remote": 0.09, "scan": 0.05}
    (tmp_path / "feeder.toml").write_text('[items]\nfolder = "scans"\ncounts = { radio = 1 }\n')
    with pytest.raises(ValidationError, match=r"counts.radio: no mesh radio.*found: remote, scan"):
        load_feeder_config(tmp_path / "feeder.toml")
    # Validated as the API validates a client's scenario (no READ_FILES context), nothing is
    # opened: its paths are confined to the mesh directory before any file is read.
    sent = FeederConfig.model_validate({"items": {"folder": "/nonexistent", "counts": {"radio": 1}}})
    assert sent.items.counts == {"radio": 1}
