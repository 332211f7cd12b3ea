"""Uploaded shapes: a mesh (STL, OBJ or PLY) and its mass, validated and turned into a clump.

The bytes are parsed by ``dem.mesh.load_mesh`` with an allow-listed type taken from the file
name's extension (never a path the user sent; archives refused), within the configured byte and
face limits. A mesh that fails validation is a 422 whose message is ``dem``'s own: it says what
to fix. The stored shape keeps the original bytes, the validation report and a clump summary;
the validated mesh, in metres, is also kept where workers read it
(``dem.scenarios.paths.shape_file``), so a scenario can feed it by id (``items.uploaded``).

Meshes are parsed and clumped one at a time, on one thread of the server process (``MESH_WORK``):
each holds a few hundred MB while it runs, and uploads side by side multiplied that (four 327k-face
meshes took the server from 390 MB to 1.2 GB). One thread, not a lock: the allocator keeps freed
memory per thread (arena), so the same work on the request threads in turn still grew the process
by each thread's share. Further uploads wait their turn.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path, PurePath
from typing import Any

from api.auth import Principal
from api.errors import InvalidInputError, NotFoundError, PayloadTooLargeError
from api.models import ShapeRow
from api.schemas import ShapePage, ShapeRead, page_of
from api.settings import Settings
from api.store import SqlStore, new_id
from dem.scenarios.paths import shape_file

log = logging.getLogger(__name__)

NAME_MAX_LENGTH = 200
MESH_WORK = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mesh")


def upload_shape(
    store: SqlStore, settings: Settings, principal: Principal, *, filename: str, data: bytes, mass: float,
    scale: float, n_spheres: int | None, name: str | None,
) -> ShapeRead:
    from dem.clumping import make_clump
    from dem.mesh import ALLOWED_FILE_TYPES, MeshError, MeshLimits, load_mesh

    if len(data) > settings.max_upload_bytes:
        raise PayloadTooLargeError(
            f"the mesh is {len(data)} bytes, more than DEMCAL_MAX_UPLOAD_BYTES = {settings.max_upload_bytes}"
        )
    suffix = PurePath(filename or "").suffix.lower().lstrip(".")
    if suffix not in ALLOWED_FILE_TYPES:
        raise InvalidInputError(
            f"file {filename!r}: send a mesh ending in {', '.join('.' + t for t in ALLOWED_FILE_TYPES)}"
        )
    if not (math.isfinite(mass) and mass > 0):
        raise InvalidInputError(f"mass must be a positive number of kilograms (got {mass})")
    display_name = (name or PurePath(filename).stem or "shape")[:NAME_MAX_LENGTH]
    shape_id = new_id("sh-")
    limits = MeshLimits(max_faces=settings.max_mesh_faces)

    def work():
        mesh, report = load_mesh(data, suffix, scale=scale, limits=limits)
        clump = make_clump(
            mesh, mass=mass, n_spheres=n_spheres, name=display_name, cache_dir=settings.data_dir / "clumps"
        )
        _keep_for_workers(mesh, shape_file(settings.data_dir, shape_id))
        return report, clump

    try:
        report, clump = MESH_WORK.submit(work).result()
    except MeshError as exc:
        raise InvalidInputError(f"file {filename!r}: {exc}") from None
    summary = {
        "n_spheres": clump.n_spheres, "mass": clump.mass, "volume": clump.volume,
        "inertia": [float(v) for v in clump.inertia],
        "equivalent_diameter": clump.equivalent_diameter, "max_error": clump.max_error,
        "radius_min": float(clump.radius.min()), "radius_max": float(clump.radius.max()),
    }
    row = ShapeRow(
        id=shape_id, owner=principal.owner, name=display_name, file_type=suffix, mass=mass,
        n_bytes=len(data), sha256=hashlib.sha256(data).hexdigest(), data=data,
        report=report.to_dict(), clump=summary,
    )
    store.add_shape(row)
    log.info("shape %s (%s, %d faces) stored for %s", row.id, suffix, report.n_faces, principal.owner)
    return ShapeRead.model_validate(row)


def get_shape(store: SqlStore, shape_id: str, principal: Principal) -> ShapeRead:
    return ShapeRead.model_validate(store.get_shape(shape_id, principal.visible_to))


def list_shapes(store: SqlStore, principal: Principal, limit: int, offset: int) -> ShapePage:
    page = store.list_shapes(principal.visible_to, limit, offset)
    return page_of(ShapePage, ShapeRead, page, limit, offset)


def delete_shape(store: SqlStore, settings: Settings, shape_id: str, principal: Principal) -> None:
    store.get_shape(shape_id, principal.visible_to)
    store.delete_shape(shape_id)
    shape_file(settings.data_dir, shape_id).unlink(missing_ok=True)


def _keep_for_workers(mesh, path: Path) -> None:
    """Write the validated mesh (metres) where workers read it; whole or not at all."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial")
    mesh.export(partial, file_type="ply")
    os.replace(partial, path)


def attach_uploaded_shapes(
    store: SqlStore, principal: Principal, scenario: dict[str, Any], data_dir: Path
) -> dict[str, Any]:
    """A scenario feeding uploaded shapes (``items.uploaded``), checked: every id in
    ``items.counts`` is a shape of this key's owner, kept where workers read it; their masses are
    the uploads' own. 422 otherwise, naming the id."""
    items = scenario.get("items")
    if not isinstance(items, dict) or not items.get("uploaded"):
        return scenario
    masses = dict(items.get("masses") or {})
    for shape_id in items.get("counts") or {}:
        try:
            row = store.get_shape(shape_id, principal.visible_to)
        except NotFoundError:
            raise InvalidInputError(
                f"scenario.items.counts: no uploaded shape {shape_id!r} of yours; with uploaded = true "
                "the counts name shapes by id (list them with GET /api/v1/shapes)"
            ) from None
        if not shape_file(data_dir, shape_id).is_file():
            raise InvalidInputError(
                f"scenario.items.counts: shape {shape_id!r} was uploaded before shapes could be fed by id; "
                "upload its mesh again (POST /api/v1/shapes) and use the new id"
            )
        masses[shape_id] = row.mass
    return {**scenario, "items": {**items, "masses": masses}}
