r"""The angle of repose of a heap, fitted from the positions of its spheres (no images).

Method (the "surface profile" measurement of heap tests, e.g. ISO 4324's cone read off in
sectors; Zhou et al., Powder Technol. 125 (2002) 45 measure DEM heaps the same way):

1. Every sphere on the plate contributes its top point ``z + r`` at its horizontal distance
   ``rho`` from the heap axis (the lifted cylinder's axis).
2. The heap is cut into ``sectors`` equal azimuthal sectors and into radial bins of
   ``bin_width`` sphere diameters; the free surface in a (sector, bin) cell is the highest top
   point in it.
3. The heap's foot radius ``R`` is the largest ``rho`` whose top lies higher than ``toe_height``
   diameters (single grains rolled away from the heap do not count).
4. In each sector a straight line ``h(rho) = h0 - tan(alpha) rho`` is fitted by least squares to
   the surface cells with centres between ``inner R`` and ``outer R``: the rounded apex and the
   toe, where the surface is not a cone, are left out.
5. The angle is that of one line fitted to the cells of all sectors together (each sector's own
   line gives ``sector_angles_deg``; their standard deviation says how round the heap is). Its
   standard error ``angle_se_deg`` is the least-squares one, from the residuals of the cells
   about the line (``s^2 / sum (rho - mean rho)^2`` for the slope), carried to the angle by
   ``d alpha = d slope / (1 + slope^2)``: how well one heap's surface determines its angle. The
   height is the highest top point.

The choices (sectors, bin width, inner and outer fractions) move the mean angle of a few heaps
by less than that mean's standard error (``tests/dem/test_heap.py`` checks this); the fit is
exact on a sphere-covered cone (the analytic case). Pure numpy, shared by every engine: the LIGGGHTS adapter
reads the final positions back and calls the same ``fit_heap``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import Field

from dem.scenarios.base import Section


class FitConfig(Section):
    """How the heap's surface is read (see the module docstring)."""

    sectors: int = Field(8, ge=1, le=72, description="Azimuthal sectors fitted separately.")
    bin_width: float = Field(1.0, gt=0.2, le=5, description="Radial bin width, in sphere diameters.")
    inner: float = Field(0.2, ge=0, lt=1, description="Fitted range starts at this fraction of R.")
    outer: float = Field(0.8, gt=0, le=1, description="Fitted range ends at this fraction of R.")
    toe_height: float = Field(
        1.0, ge=0, description="The heap's foot: where the surface drops below this many diameters."
    )


class HeapFitError(ValueError):
    """The heap is too small or too flat to fit a surface line; the message says what to change."""


@dataclass(frozen=True)
class HeapFit:
    angle_deg: float
    spread_deg: float  # standard deviation over the sectors
    angle_se_deg: float  # standard error of angle_deg from the fit's residuals
    height: float  # m
    radius: float  # R, the heap's foot radius, m
    sector_angles_deg: tuple[float, ...]


def fit_heap(
    points: np.ndarray,
    radii: np.ndarray,
    centre: tuple[float, float] = (0.0, 0.0),
    floor_z: float = 0.0,
    config: FitConfig | None = None,
    diameter: float | None = None,
) -> HeapFit:
    """Fit the heap formed by spheres at ``points`` (n, 3) with ``radii`` (n,) on a plate at
    ``floor_z``; ``diameter`` (default: the mean sphere diameter) is the unit of the bin width
    and the toe height."""
    config = config or FitConfig()
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    radii = np.asarray(radii, dtype=float).reshape(-1)
    on_plate = points[:, 2] > floor_z - radii  # spheres that fell off the plate are below it
    points, radii = points[on_plate], radii[on_plate]
    if len(points) < 10:
        raise HeapFitError(f"only {len(points)} spheres on the plate; a heap needs many more")
    if config.inner >= config.outer:
        raise HeapFitError(f"fit.inner ({config.inner}) must be below fit.outer ({config.outer})")
    unit = float(diameter if diameter is not None else 2 * radii.mean())
    dx, dy = points[:, 0] - centre[0], points[:, 1] - centre[1]
    rho = np.hypot(dx, dy)
    top = points[:, 2] + radii - floor_z
    standing = top > config.toe_height * unit
    if not np.any(standing):
        raise HeapFitError("no sphere stands higher than fit.toe_height: the material spread flat")
    foot = float(rho[standing].max())
    width = config.bin_width * unit
    n_bins = max(1, int(math.ceil(foot / width)))
    sector = np.minimum(
        ((np.arctan2(dy, dx) + math.pi) / (2 * math.pi) * config.sectors).astype(int), config.sectors - 1
    )
    radial = np.minimum((rho / width).astype(int), n_bins)  # n_bins collects everything beyond R
    surface = np.full((config.sectors, n_bins + 1), -np.inf)
    np.maximum.at(surface, (sector, radial), top)
    centres = (np.arange(n_bins + 1) + 0.5) * width
    fitted = (centres >= config.inner * foot) & (centres <= config.outer * foot)
    angles, xs, hs = [], [], []
    for s in range(config.sectors):
        use = fitted & np.isfinite(surface[s])
        if use.sum() < 3:
            continue
        slope = np.polyfit(centres[use], surface[s, use], 1)[0]
        angles.append(math.degrees(math.atan(-slope)))
        xs.append(centres[use])
        hs.append(surface[s, use])
    if len(angles) < max(1, config.sectors // 2):
        raise HeapFitError(
            f"the heap (foot radius {foot * 1e3:.1f} mm = {foot / unit:.1f} diameters) has too few "
            f"surface cells between fit.inner and fit.outer; use more particles, a smaller "
            f"fit.bin_width or fewer fit.sectors"
        )
    x, h = np.concatenate(xs), np.concatenate(hs)
    pooled, intercept = np.polyfit(x, h, 1)
    residual = h - (pooled * x + intercept)
    slope_se = math.sqrt(float(residual @ residual) / (len(x) - 2) / float(np.sum((x - x.mean()) ** 2)))
    return HeapFit(
        angle_deg=math.degrees(math.atan(-pooled)),
        spread_deg=float(np.std(angles)),
        angle_se_deg=math.degrees(slope_se / (1.0 + pooled * pooled)),
        height=float(top.max()),
        radius=foot,
        sector_angles_deg=tuple(angles),
    )
