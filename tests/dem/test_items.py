"""The feeder's item catalogue (issue 4, items): cited sizes and masses, per-item spread, the
camera's lens barrel, clumps consistent with each item's mesh, user meshes from a folder."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from dem.clumping import signed_distance
from dem.scenarios.items import (
    CATALOGUE,
    CITED_RANGES,
    FOLDER_MESH_FACES,
    KINDS,
    ItemsError,
    default_items,
    items_from_folder,
    nominal_volume,
)

SPREAD = 0.03


@pytest.fixture(scope="module")
def items(tmp_path_factory):
    cache = tmp_path_factory.mktemp("clumps")
    return default_items(np.random.default_rng(42), spread=SPREAD, resolution=16, cache_dir=cache)


@pytest.mark.parametrize("kind", KINDS)
def test_nominal_items_lie_within_the_cited_product_ranges(kind):
    spec = CATALOGUE[kind]

    for key, (low, high) in CITED_RANGES[kind].items():
        assert low <= getattr(spec, key) <= high, f"{kind}.{key}"


@pytest.mark.parametrize("kind", KINDS)
def test_nominal_meshes_are_closed_with_the_spec_dimensions(kind):
    spec = CATALOGUE[kind]

    mesh = spec.mesh()

    assert mesh.is_watertight
    expected_depth = spec.thickness + spec.lens_protrusion
    np.testing.assert_allclose(mesh.extents, [spec.length, spec.width, expected_depth], rtol=1e-6)
    assert nominal_volume(kind) == pytest.approx(mesh.volume)


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
        for key, (low, high) in CITED_RANGES[item.kind].items():
            value = getattr(spec, key)
            assert low * (1 - SPREAD) <= value <= high * (1 + SPREAD), f"{item.name}.{key}"
        assert item.mass == pytest.approx(spec.mass)
        depth = spec.thickness + spec.lens_protrusion
        np.testing.assert_allclose(item.mesh.extents, [spec.length, spec.width, depth], rtol=1e-6)


def test_each_item_clump_has_its_own_mesh_mass_properties_and_inscribed_spheres(items):
    for item in items[::7]:
        reference = item.mesh.copy()
        reference.density = item.mass / reference.volume

        clump = item.clump

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
    assert scan.clump.mass == pytest.approx(0.05)


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
