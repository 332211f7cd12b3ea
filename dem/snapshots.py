"""Snapshots of a running simulation: body poses and velocities at a chosen interval, saved as
one compressed ``.npz`` with the sphere layout of every body so that a viewer can rebuild the
scene (``dem/vtk.py`` writes ParaView files from it).

A ``SnapshotRecorder`` is an ``on_chunk`` observer: it records at the first chunk end at or after
each multiple of its interval, so choose ``chunk_time`` as a divisor of the interval for exact
times. It only reads the simulation.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np


class SnapshotRecorder:
    """Collects (t, pos, quat, vel, omega, active) every ``interval`` simulated seconds."""

    def __init__(self, interval: float) -> None:
        if not interval > 0:
            raise ValueError(f"snapshot interval must be > 0 s, got {interval!r}")
        self.interval = interval
        self._next = interval  # the initial state is recorded only on request (``record``)
        self.frames: list[dict[str, np.ndarray | float]] = []
        self._layout: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def __call__(self, sim) -> None:
        # A half-step tolerance so that chunk ends landing on a multiple by rounding still count.
        if sim.t + 0.5 * sim.dt < self._next:
            return
        self.record(sim)
        while self._next <= sim.t + 0.5 * sim.dt:
            self._next += self.interval

    def record(self, sim) -> None:
        b = sim.bodies
        self.frames.append(
            {
                "t": sim.t,
                "pos": b.pos.copy(),
                "quat": b.quat.copy(),
                "vel": b.vel.copy(),
                "omega": b.omega.copy(),
                "active": b.active.copy(),
            }
        )
        self._layout = (sim.spheres.body.copy(), sim.spheres.radius.copy(), sim.spheres.offset.copy())

    def save(self, path: str | os.PathLike) -> Path:
        """Write all frames to ``path`` (.npz) atomically; bodies added later are zero-padded."""
        path = Path(path)
        if not self.frames or self._layout is None:
            raise ValueError("no snapshot recorded yet")
        n = max(len(f["pos"]) for f in self.frames)

        def stack(key: str, width: int) -> np.ndarray:
            out = np.zeros((len(self.frames), n, width)) if width else np.zeros((len(self.frames), n), bool)
            for k, frame in enumerate(self.frames):
                out[k, : len(frame[key])] = frame[key]
            return out

        sphere_body, radius, offset = self._layout
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".npz", delete=False) as tmp:
            np.savez_compressed(
                tmp,
                t=np.array([f["t"] for f in self.frames]),
                pos=stack("pos", 3),
                quat=stack("quat", 4),
                vel=stack("vel", 3),
                omega=stack("omega", 3),
                active=stack("active", 0),
                sphere_body=sphere_body,
                sphere_radius=radius,
                sphere_offset=offset,
            )
        os.replace(tmp.name, path)
        return path


def load(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of a snapshot file."""
    with np.load(path) as data:
        return {key: data[key] for key in data.files}
