"""Which files a scenario sent through the API may name: only those inside the mesh directory
(``$DEMCAL_DATA_DIR/meshes``), given relative to it.

A scenario's ``tray.mesh_file`` and ``items.folder`` are opened by a worker. Taken from a client
as they are, they let any API key make a worker read any path it can (``/etc/shadow``), and the
error text would tell "not a readable mesh" from "does not exist". So a path is resolved against
the server's mesh directory (symbolic links followed) and refused with a 422, before anything is
opened, when it lands outside; the stored scenario carries the path relative to the mesh
directory, which each worker resolves against its own (``dem/scenarios/paths.py``). Files get
there by the operator (or a shared volume); ``demcal calibrate`` and ``demcal simulate`` read
local files as before.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from api.errors import InvalidInputError
from dem.scenarios.paths import MESH_SUBDIR, inside, mesh_root, path_tables


def confine_paths(scenario: dict[str, Any], data_dir: Path) -> dict[str, Any]:
    """The scenario with its paths, at any depth (``path_tables``), made relative to the mesh
    directory; 422 for any other path."""
    root = mesh_root(data_dir)
    confined = copy.deepcopy(scenario)
    for where, table, field in list(path_tables(confined)):
        given = str(table[field])
        resolved = inside(root, given)
        if resolved is None:
            raise InvalidInputError(
                f"scenario.{where}: a scenario sent to the API may name only files inside the "
                f"server's mesh directory ($DEMCAL_DATA_DIR/{MESH_SUBDIR}), as a path relative to "
                f"it; {given!r} is outside"
            )
        table[field] = str(resolved.relative_to(root))
    return confined
