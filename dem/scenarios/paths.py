"""The files a scenario config names, and where a worker finds them: in its own data directory.

A scenario's ``tray.mesh_file`` and ``items.folder`` name files the engine opens. A scenario sent
through the API names them relative to the mesh directory (``$DEMCAL_DATA_DIR/meshes``) and is
stored so; each process that runs a trial resolves them against *its own* data directory
(``resolve_paths``), so a worker on another machine reads its copy (or a shared volume) and never
a path of the server's. An absolute path (a local ``demcal calibrate`` or ``simulate`` reading
the user's own files) is used as it is.

Shapes uploaded to the service (``items.uploaded``: ``items.counts`` names them by id) are
kept as ``$DEMCAL_DATA_DIR/shapes/<id>.ply`` in metres, outside the mesh directory so that no
scenario can name another owner's shape by path; for the engine they are a folder of meshes.

Must not: open the files; the scenario does that, and says what is wrong with them.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from pathlib import Path
from typing import Any

MESH_SUBDIR = "meshes"
SHAPES_SUBDIR = "shapes"
# (section, field) of every path a scenario config may hold, at any depth (``path_tables``).
SCENARIO_PATHS = (("tray", "mesh_file"), ("items", "folder"))
# The validation context of a config read from the user's own files (``demcal simulate`` and
# ``calibrate``): its validators may then look into the folders it names. A scenario sent to the
# API is validated without it, so nothing is opened before its paths are confined.
READ_FILES = {"read_files": True}


class ScenarioPathError(ValueError):
    """A relative path that leaves the mesh directory (``..``, a symbolic link out of it)."""


def mesh_root(data_dir: Path | str) -> Path:
    """The mesh directory of a data directory, absolute with symbolic links resolved."""
    return (Path(data_dir) / MESH_SUBDIR).resolve()


def shape_file(data_dir: Path | str, shape_id: str) -> Path:
    """Where an uploaded shape's mesh (metres) is kept for the engine."""
    return Path(data_dir).resolve() / SHAPES_SUBDIR / f"{shape_id}.ply"


def inside(root: Path, given: str) -> Path | None:
    """``given`` resolved against ``root`` if it stays inside it, else None."""
    resolved = (root / given).resolve()  # an absolute ``given`` replaces the root
    return resolved if "\x00" not in given and resolved.is_relative_to(root) else None


def path_tables(scenario: dict[str, Any], location: tuple[str, ...] = ()) -> Iterator[tuple[str, dict, str]]:
    """(dotted location, the table holding it, its key) of every path a scenario config names,
    at any depth: ``tray.mesh_file`` and ``items.folder`` at the top, an angle of repose's
    ``particles.items.folder``, a combined scenario's ``parts.<name>.items.folder``: confining
    only the top-level ones let a nested folder name any path of the worker's."""
    fields = dict(SCENARIO_PATHS)
    for key, value in scenario.items():
        if not isinstance(value, dict):
            continue
        field = fields.get(key)
        if field is not None and value.get(field) not in (None, ""):
            yield ".".join((*location, key, field)), value, field
        yield from path_tables(value, (*location, key))


def resolve_paths(scenario: dict[str, Any], data_dir: Path | None) -> dict[str, Any]:
    """The scenario with its relative paths resolved inside ``data_dir``'s mesh directory and its
    uploaded shapes as the folder that holds them (a copy; absolute paths kept). With no
    ``data_dir``, relative paths stay relative to the working directory."""
    if data_dir is None:
        return scenario
    root = mesh_root(data_dir)
    resolved = copy.deepcopy(scenario)
    for where, table, field in list(path_tables(resolved)):
        given = str(table[field])
        if Path(given).is_absolute():
            continue
        path = inside(root, given)
        if path is None:
            raise ScenarioPathError(f"{where} {given!r} leaves the mesh directory {root}")
        table[field] = str(path)
    items = resolved.get("items")
    if isinstance(items, dict) and items.get("uploaded"):
        folder = shape_file(data_dir, "-").parent
        resolved["items"] = {**items, "uploaded": False, "folder": str(folder)}
    return resolved
