"""A trial's snapshots as compact JSON for the dashboard's replay:
``GET /api/v1/studies/{study_id}/trials/{trial_id}/replay``.

Where snapshots live: ``Settings.snapshot_root / <trial_id>``, a directory in the format
``dem/scenarios/render.py`` documents (``scene.npz``, ``frame_NNNNNN.npz``, ``summary.json``),
written by whatever ran the trial with snapshots on. A trial without that directory answers 404
with a message saying so; the page then shows the discharge curve only.

The JSON sends the tray (vertices at rest, triangles, tilt, vibration) and each item's convex
hull once (body-frame points and their triangles), and per frame only positions, quaternions,
states and the tray's displacement, rounded to 0.1 mm (the displacement to 10 um) and 1e-4; the
browser places the hulls, for the top view and the 3D view alike. That is about 8 numbers per
item and frame instead of a polygon, so a 650-frame run of 30 items is a few hundred kB. At most
``max_frames`` evenly spaced frames are sent (the last always).

It reads files only: it never runs or changes a simulation, and it serves nothing before the API
key has been checked against the trial's study (the same rule as every other trial endpoint).
The path is built from the trial id stored in the database, never from the request text.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse

from api.deps import ApiKeyDep, SettingsDep, StoreDep
from api.errors import NotFoundError
from api.settings import SNAPSHOT_SUBDIR

POSITION_DECIMALS = 4  # metres: 0.1 mm, far below an item's size
OFFSET_DECIMALS = 5  # metres: 10 um, well below the tray's vibration amplitude (mm)
QUATERNION_DECIMALS = 4

router = APIRouter(prefix="/api/v1/studies/{study_id}/trials", tags=["trials"])


def replay_document(directory: Path, max_frames: int) -> dict[str, Any]:
    """The replay JSON of one snapshot directory (raises SnapshotError if it is incomplete)."""
    # Imported on use: the API process needs the DEM's snapshot reader only for this route, so
    # creating the app does not depend on the scenario modules.
    from dem.scenarios.render import load_run

    run = load_run(directory)
    step = max(1, int(np.ceil(len(run.frames) / max_frames)))
    frames = run.frames[::step]
    if frames[-1] is not run.frames[-1]:
        frames.append(run.frames[-1])
    vertices = np.round(run.tray_vertices, POSITION_DECIMALS)
    vibration = run.vibration
    return {
        "tray": {
            "vertices": vertices.tolist(),
            "faces": run.tray_faces.tolist(),
            "tilt_deg": run.tilt_deg,
            "vibration": None if vibration is None else {
                "direction": list(vibration.direction),
                "angle_deg": round(vibration.angle_deg, 3),
                "amplitude": vibration.amplitude,
                "frequency": vibration.frequency,
                "start": vibration.start,
            },
        },
        "items": [
            {
                "name": name,
                "kind": kind,
                "hull": np.round(hull, POSITION_DECIMALS).tolist(),
                "faces": faces.tolist(),
            }
            for name, kind, hull, faces in zip(run.names, run.kinds, run.hulls, run.hull_faces, strict=True)
        ],
        "retained": run.retained.tolist(),
        "frames": {
            "t": [round(frame.t, 4) for frame in frames],
            "pos": [np.round(frame.pos, POSITION_DECIMALS).tolist() for frame in frames],
            "quat": [np.round(frame.quat, QUATERNION_DECIMALS).tolist() for frame in frames],
            "state": [frame.state.astype(int).tolist() for frame in frames],
            "tray_offset": [np.round(frame.tray_offset, OFFSET_DECIMALS).tolist() for frame in frames],
        },
        "frames_total": len(run.frames),
    }


@router.get("/{trial_id}/replay")
def trial_replay(
    study_id: str,
    trial_id: str,
    principal: ApiKeyDep,
    store: StoreDep,
    settings: SettingsDep,
    max_frames: Annotated[int, Query(ge=2, le=5000, description="Most frames to send.")] = 400,
) -> JSONResponse:
    """The trial's snapshot frames (top-view and 3D replay); 404 when the trial kept none."""
    from dem.scenarios.render import SnapshotError

    store.get_study(study_id, principal.visible_to)
    row = store.get_trial(study_id, trial_id)
    directory = settings.snapshot_root / row.id
    try:
        document = replay_document(directory, max_frames)
    except SnapshotError as exc:
        raise NotFoundError(
            f"trial {trial_id!r} has no snapshots to replay ({exc}); snapshots are kept in "
            f"<DEMCAL_DATA_DIR>/{SNAPSHOT_SUBDIR}/<trial id>/"
        ) from None
    document["trial_id"] = row.id
    # Snapshots do not change once written; the key decides who may see them, so private only.
    return JSONResponse(document, headers={"Cache-Control": "private, max-age=300"})
