"""Which files a scenario sent through the API may name: only those inside the server's mesh
directory (``$DEMCAL_DATA_DIR/meshes``).

A scenario's ``tray.mesh_file`` and ``items.folder`` are opened by a worker. Taken from a client
as they are, they let any API key make the server read any path it can (``/etc/shadow``), and
the error text would tell "not a mesh" from "does not exist". So a path is resolved against the
mesh directory (symbolic links followed) and refused with a 422, before anything is opened, when
it lands outside; the stored scenario carries the resolved absolute path. Files get there by the
operator (or a volume); ``demcal calibrate`` and ``demcal simulate`` read local files as before.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from api.errors import InvalidInputError

MESH_SUBDIR = "meshes"
# (section, field) of every path a scenario may hold.
SCENARIO_PATHS = (("tray", "mesh_file"), ("items", "folder"))


def mesh_root(data_dir: Path) -> Path:
    return (Path(data_dir) / MESH_SUBDIR).resolve()


def confine_paths(scenario: dict[str, Any], data_dir: Path) -> dict[str, Any]:
    """The scenario with its paths resolved inside the mesh directory; 422 for any other path."""
    root = mesh_root(data_dir)
    confined = dict(scenario)
    for section, field in SCENARIO_PATHS:
        values = scenario.get(section)
        if not isinstance(values, dict) or values.get(field) in (None, ""):
            continue
        given = str(values[field])
        resolved = (root / given).resolve()  # an absolute ``given`` replaces the root
        if "\x00" in given or not resolved.is_relative_to(root):
            raise InvalidInputError(
                f"scenario.{section}.{field}: a scenario sent to the API may name only files inside "
                f"the server's mesh directory ($DEMCAL_DATA_DIR/{MESH_SUBDIR}), as a path relative "
                f"to it; {given!r} is outside"
            )
        confined[section] = {**values, field: str(resolved)}
    return confined
