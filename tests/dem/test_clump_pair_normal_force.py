"""How much the clump contact law's shallow contacts pull (``dem/contact.py``, "Clumps").

A body pair with several sphere contacts is one spring-dashpot in the Lehmer mean
M = sum delta^3 / sum delta^2 of its overlaps; contact k carries f_k = F dM/d(delta_k), a pull for a
contact shallower than 2 M / 3. Checked on the feeder's clumps (its 30 items at 12 spheres, from
``dem.clumping``) in poses within the law's validity (every overlap at most ``OVERLAP_LIMIT`` of its
sphere's radius):

* one contact pulls with at most F / 3 (min over delta_k of delta_k (3 delta_k - 2 M) is -M^2 / 3,
  and M^2 <= sum delta^2), against a plane and against another clump;
* a clump on a plane (a body on a wall facet, all normals parallel) is pushed with at least F / 10:
  30,000 random poses stay above 0.19 F (0.61 F at their 0.1 % quantile), and a local search from
  the worst of them finds 0.105 F (a camera's large sphere at the validity limit with five small
  ones at 0.13 of their radius); the Coulomb cap's normal force is this net force exactly;
* two clumps in random poses: the net force along the pair's normal (the friction weights' mean
  normal, sum_k w_k n_k, w_k = delta_k^2 / sum delta^2) is at least 0.3 of what F shared by those
  non-negative weights pushes along it (0.53 at its lowest). Only in random poses: a search finds
  poses where the Coulomb cap's normal F sum_k dM/d(delta_k) is negative (-0.11 F; ``dem/forces.py``
  caps it at 0) and, near a sphere wedged between two of the other clump's (normals nearly
  opposed), a net force against that normal (-0.35 F). No positive bound holds for every pose of
  two clumps.

The forces come from the law's kernels (``share_sums``, ``shared_overlap``, ``contact_share``), as
``dem/forces.py`` calls them; the geometry is computed here.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from dem.contact import contact_share, share_sums, shared_overlap
from dem.result import OVERLAP_LIMIT
from dem.scenarios.feeder import make_items
from dem.scenarios.feeder_config import FeederConfig

POSES = 1000  # random poses per item on the plane
SEARCHED = 3  # the worst random poses of each kind that a local search starts from
PAIR_BATCHES, PAIR_POSES = 40, 2000  # random item pairs x poses (about 4,000 with several contacts)


@pytest.fixture(scope="module")
def feeder_clumps():
    config = FeederConfig().items
    items = make_items(config.model_copy(update={"representation": "clump"}), np.random.default_rng(0))
    assert {item.shape.radius.size for item in items} == {config.resolution}
    return [(item.kind, item.shape) for item in items]


def shared_law(delta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(dM/d(delta_k), w_k, sum_k dM/d(delta_k) as the Coulomb cap takes it) of one pair's
    touching contacts, static (d(delta)/dt = 0)."""
    sums = np.sum([share_sums(float(d), 0.0) for d in delta], axis=0)
    m, _, net = shared_overlap((sums[0], sums[1], sums[2], sums[3], sums[4]))
    share, weight = np.array([contact_share(float(d), m, sums[1]) for d in delta]).T
    return share, weight, net


def depths(rng, n: int) -> np.ndarray:
    """Deepest overlaps in sphere radii, log-uniform up to the validity limit."""
    return np.exp(rng.uniform(np.log(1e-4), np.log(OVERLAP_LIMIT), n))


def on_a_plane(clump, rotvec: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Overlaps (pose, sphere; <= 0 where apart) with the plane z = 0 of ``clump`` turned by each
    rotation vector and pressed in until its lowest sphere overlaps by ``depth`` of its radius."""
    centres = np.einsum("pij,kj->pki", Rotation.from_rotvec(rotvec).as_matrix(), clump.offset)
    bottom = centres[:, :, 2] - clump.radius
    lowest = np.argmin(bottom, axis=1)
    press = depth * clump.radius[lowest]
    return bottom[np.arange(len(bottom)), lowest][:, None] - bottom + press[:, None]


def plane_net_force(clump, overlap: np.ndarray) -> float | None:
    """The pair's net normal force per F for these overlaps with a plane (all normals parallel),
    checked to be the Coulomb cap's normal force; None where an overlap is beyond validity."""
    touching = overlap > 0
    if np.any(overlap[touching] > OVERLAP_LIMIT * clump.radius[touching]):
        return None
    share, _, cap = shared_law(overlap[touching])
    assert cap == pytest.approx(share.sum(), abs=1e-12)
    return float(share.sum())


def searched_plane_net_force(clump, x: np.ndarray) -> float:
    """``plane_net_force`` in pose x = (rotation vector, depth), 10 beyond validity (a penalty)."""
    net = plane_net_force(clump, on_a_plane(clump, x[None, :3], np.array([abs(x[3])]))[0])
    return 10.0 if net is None else net


def against_a_clump(a, b, rng, n: int):
    """(overlaps, normals from b to a) of ``n`` random poses of clump b pushed along a random
    direction into clump a (random pose) until its deepest sphere pair overlaps by a random depth
    of the smaller radius. Poses whose line of approach misses a are left out."""
    rel = (
        np.einsum("pij,kj->pki", Rotation.random(n, random_state=rng).as_matrix(), a.offset)[:, :, None, :]
        - np.einsum("pij,kj->pki", Rotation.random(n, random_state=rng).as_matrix(), b.offset)[:, None, :, :]
    )  # (pose, sphere of a, sphere of b, 3): a's centre minus b's, both bodies at the origin
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    touching = a.radius[:, None] + b.radius[None, :]
    smaller = np.minimum(a.radius[:, None], b.radius[None, :])
    reach = touching[None] - depths(rng, n)[:, None, None] * smaller[None]
    along = np.einsum("pijk,pk->pij", rel, u)
    across2 = np.sum(rel**2, axis=3) - along**2
    meets = reach**2 > across2
    # b at s u: the pair (i, j) overlaps by its depth at s = along + sqrt(reach^2 - across^2) on
    # its way out; beyond the largest such s every pair overlaps less.
    exit_s = np.where(meets, along + np.sqrt(np.where(meets, reach**2 - across2, 0.0)), -np.inf)
    s = exit_s.max(axis=(1, 2))
    found = np.isfinite(s)
    diff = rel[found] - s[found, None, None, None] * u[found, None, None, :]
    dist = np.linalg.norm(diff, axis=3)
    overlap = touching[None] - dist
    normal = diff / dist[..., None]
    valid = np.all((overlap <= OVERLAP_LIMIT * smaller[None]) | (overlap <= 0), axis=(1, 2))
    return [(overlap[p][overlap[p] > 0], normal[p][overlap[p] > 0]) for p in np.flatnonzero(valid)]


def test_one_sphere_contact_of_a_clump_pulls_with_at_most_a_third_of_the_pair_force(feeder_clumps):
    rng = np.random.default_rng(1)
    shares = []
    for _, clump in feeder_clumps:
        overlap = on_a_plane(clump, Rotation.random(POSES, random_state=rng).as_rotvec(), depths(rng, POSES))
        shares += [shared_law(row[row > 0])[0] for row in overlap]
    for _ in range(PAIR_BATCHES // 4):
        a, b = (feeder_clumps[k][1] for k in rng.integers(len(feeder_clumps), size=2))
        shares += [shared_law(delta)[0] for delta, _ in against_a_clump(a, b, rng, PAIR_POSES)]

    pulls = np.concatenate(shares)
    assert np.sum(pulls < 0) > 1000  # shallow contacts do pull
    assert pulls.min() >= -1 / 3


def test_clump_on_a_facet_is_pushed_by_at_least_a_tenth_of_its_pair_force(feeder_clumps):
    rng = np.random.default_rng(2)
    random, worst = [], {}
    for kind, clump in feeder_clumps:
        rotvec, depth = Rotation.random(POSES, random_state=rng).as_rotvec(), depths(rng, POSES)
        poses = np.column_stack([rotvec, depth])
        for x, overlap in zip(poses, on_a_plane(clump, rotvec, depth), strict=True):
            net = plane_net_force(clump, overlap)
            if net is not None:
                random.append(net)
                worst.setdefault(kind, []).append((net, x, clump))
    searched = [
        minimize(lambda y, c=clump: searched_plane_net_force(c, y), x, method="Nelder-Mead",
                 options={"xatol": 1e-10, "fatol": 1e-10, "maxiter": 3000}).fun
        for poses in worst.values()
        for _, x, clump in sorted(poses, key=lambda pose: pose[0])[:SEARCHED]
    ]  # fmt: skip

    assert len(random) > 0.9 * POSES * len(feeder_clumps)
    assert min(random + searched) >= 0.1


def test_two_clumps_in_random_poses_push_apart_with_at_least_three_tenths_of_a_non_pulling_share(
    feeder_clumps,
):
    rng = np.random.default_rng(3)
    along_normal = []
    for _ in range(PAIR_BATCHES):
        a, b = (feeder_clumps[k][1] for k in rng.integers(len(feeder_clumps), size=2))
        for delta, normal in against_a_clump(a, b, rng, PAIR_POSES):
            if delta.size < 2:
                continue  # a lone contact carries F itself
            share, weight, _ = shared_law(delta)
            pushed = weight @ normal  # F shared by the non-negative weights, along the pair's normal
            along_normal.append((share @ normal) @ pushed / (pushed @ pushed))

    assert len(along_normal) > 2000
    assert min(along_normal) >= 0.3
