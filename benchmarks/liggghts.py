"""Like-for-like runs against LIGGGHTS 3.8 (Debian ``liggghts``): its ``model hooke`` constants,
the demcal materials that reproduce them, and a timed LIGGGHTS run.

LIGGGHTS' ``model hooke`` (src/normal_model_hooke.h) derives from E, nu, e and the
``characteristicVelocity`` v per contact::

    Y* = 1 / ((1 - nu^2)/E + (1 - nu^2)/E),  R* = R_i R_j / (R_i + R_j) (a wall: R_i),
    m* = m_i m_j / (m_i + m_j) (a wall: m_i)
    kn = 16/15 sqrt(R*) Y* (15 m* v^2 / (16 sqrt(R*) Y*))^(1/5),  kt = kn
    gamma_n = sqrt(4 m* kn / (1 + (pi / ln e)^2)),  gamma_t = gamma_n

demcal's law (``dem/contact.py``) has K = E D / 2 for two equal spheres, K_wall = D E E_w /
(E + E_w), K_t = 2 (1 - nu) / (2 - nu) K and C = 2 zeta(e) sqrt(K m*) with zeta the damping ratio
that gives restitution e *with* the no-attraction clamp. So for equal spheres of diameter D::

    E = 2 kn / D;   nu = 0 (K_t = K);   e = restitution_with_clamp(zeta) with
    zeta = gamma_n / (2 sqrt(kn m*)) = -ln e_L / sqrt(pi^2 + ln^2 e_L);
    the walls' material: E_w with D E E_w / (E + E_w) = kn_wall, nu = 0, the same e and mu.

LIGGGHTS' wall zeta equals its particle zeta (the same e_L), so one demcal e serves both. Both
engines clamp the normal force at zero (LIGGGHTS' ``limitForce on``, demcal always), so the
normal law is the same function; the tangential spring differs in detail (LIGGGHTS caps the
spring force, demcal the spring-plus-damper force).
"""

from __future__ import annotations

import math
import resource
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from dem.contact import ContactParams, damping_ratio, restitution_with_clamp
from dem.engines.liggghts import binary, input_header


@dataclass(frozen=True)
class Hooke:
    """One contact's constants in LIGGGHTS ``model hooke``."""

    kn: float
    kt: float
    gamma_n: float
    gamma_t: float


def liggghts_hooke(E, nu, e, r_i, m_i, r_j=None, m_j=None, v_char=1.0) -> Hooke:
    """LIGGGHTS' constants for spheres i, j of one material (j None: a wall of that material)."""
    y_eff = 1.0 / (2.0 * (1.0 - nu * nu) / E)
    r_eff = r_i if r_j is None else r_i * r_j / (r_i + r_j)
    m_eff = m_i if m_j is None else m_i * m_j / (m_i + m_j)
    sqrt_r = math.sqrt(r_eff)
    kn = 16.0 / 15.0 * sqrt_r * y_eff * (15.0 * m_eff * v_char * v_char / (16.0 * sqrt_r * y_eff)) ** 0.2
    log_e = math.log(e)
    gamma_n = math.sqrt(4.0 * m_eff * kn / (1.0 + (math.pi / log_e) * (math.pi / log_e)))
    return Hooke(kn, kn, gamma_n, gamma_n)


@dataclass(frozen=True)
class Mapping:
    """demcal materials that reproduce LIGGGHTS' constants for equal spheres of diameter D."""

    particles: ContactParams
    wall: ContactParams
    liggghts_pair: Hooke
    liggghts_wall: Hooke
    demcal_pair: Hooke
    demcal_wall: Hooke

    def worst_relative_error(self) -> float:
        pairs = ((self.liggghts_pair, self.demcal_pair), (self.liggghts_wall, self.demcal_wall))
        return max(
            abs(getattr(d, k) / getattr(lig, k) - 1.0)
            for lig, d in pairs
            for k in ("kn", "kt", "gamma_n", "gamma_t")
        )

    def describe(self) -> str:
        rows = [
            f"  {name:12s} LIGGGHTS kn {lig.kn:.6g} N/m, gamma_n {lig.gamma_n:.6g} N s/m "
            "(kt = kn, gamma_t = gamma_n); "
            f"demcal kn {d.kn:.6g}, kt {d.kt:.6g}, gamma_n {d.gamma_n:.6g}, gamma_t {d.gamma_t:.6g}"
            for name, lig, d in (
                ("sphere pair", self.liggghts_pair, self.demcal_pair),
                ("sphere-wall", self.liggghts_wall, self.demcal_wall),
            )
        ]
        p, w = self.particles, self.wall
        return "\n".join(
            [
                f"contact constants: demcal particles E {p.E:.8g} Pa, nu {p.nu}, e {p.e:.10g}, mu {p.mu}; "
                f"walls E {w.E:.8g} Pa",
                *rows,
                f"  largest relative difference {self.worst_relative_error():.1e}",
            ]
        )


def demcal_constants(E, nu, e, D, m, E_wall) -> tuple[Hooke, Hooke]:
    """demcal's (pair, wall) constants as the kernels compute them (``dem/forces.py``)."""
    zeta = damping_ratio(e)
    kt_ratio = ContactParams(E=E, nu=nu, e=e, mu=0.0).tangential_ratio
    k = E * D * D / (D + D)
    m_eff = m * m / (m + m)
    pair = Hooke(k, kt_ratio * k, 2 * zeta * math.sqrt(k * m_eff), 2 * zeta * math.sqrt(kt_ratio * k * m_eff))
    k = D * E * E_wall / (E + E_wall)
    wall = Hooke(k, kt_ratio * k, 2 * zeta * math.sqrt(k * m), 2 * zeta * math.sqrt(kt_ratio * k * m))
    return pair, wall


def mapping(E, nu, e, mu, D, rho, v_char=1.0) -> Mapping:
    """The demcal materials matching LIGGGHTS ``model hooke`` with (E, nu, e, mu) for spheres of
    diameter D and density rho (see the module docstring)."""
    m = rho * math.pi / 6.0 * D**3
    pair = liggghts_hooke(E, nu, e, D / 2, m, D / 2, m, v_char)
    wall = liggghts_hooke(E, nu, e, D / 2, m, None, None, v_char)
    zeta = pair.gamma_n / (2.0 * math.sqrt(pair.kn * m / 2.0))
    e_demcal = restitution_with_clamp(zeta)
    E_demcal = 2.0 * pair.kn / D
    E_wall = 1.0 / (D * (1.0 / wall.kn - 1.0 / (D * E_demcal)))
    particles = ContactParams(E=E_demcal, nu=0.0, e=e_demcal, mu=mu)
    wall_params = ContactParams(E=E_wall, nu=0.0, e=e_demcal, mu=mu)
    d_pair, d_wall = demcal_constants(E_demcal, 0.0, e_demcal, D, m, E_wall)
    return Mapping(particles, wall_params, pair, wall, d_pair, d_wall)


def header(skin: float) -> str:
    """The start of every benchmark input: the engine's own (``dem.engines.liggghts``)."""
    return f"\n{input_header(skin)}\n"

MATERIAL_COMMANDS = """
fix m1 all property/global youngsModulus peratomtype {E}
fix m2 all property/global poissonsRatio peratomtype {nu}
fix m3 all property/global coefficientRestitution peratomtypepair 1 {e}
fix m4 all property/global coefficientFriction peratomtypepair 1 {mu}
fix m5 all property/global characteristicVelocity scalar {v_char}
pair_style gran model hooke tangential history limitForce on
pair_coeff * *
"""


@dataclass(frozen=True)
class Timed:
    wall: float
    cpu: float
    stdout: str


def executable() -> str | None:
    """The LIGGGHTS binary (``liggghts`` on the PATH, or ``DEMCAL_LIGGGHTS``), as the engine finds it."""
    return binary()


def run(executable: str, folder: Path, input_name: str) -> Timed:
    """Run LIGGGHTS on ``folder/input_name`` (one process); wall and CPU time, start-up included."""
    start = time.perf_counter()
    cpu_start = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(
        [executable, "-in", input_name], cwd=folder, capture_output=True, text=True, errors="replace"
    )
    wall = time.perf_counter() - start
    cpu_end = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = cpu_end.ru_utime + cpu_end.ru_stime - cpu_start.ru_utime - cpu_start.ru_stime
    if done.returncode != 0 or "ERROR" in done.stdout:
        raise RuntimeError(f"LIGGGHTS failed:\n{done.stdout[-3000:]}\n{done.stderr[-2000:]}")
    return Timed(wall, cpu, done.stdout)


def read_last_dump(path: Path) -> list[list[float]]:
    """The atom rows of the last snapshot of a LIGGGHTS ``dump custom`` file."""
    text = path.read_text()
    block = text.rsplit("ITEM: ATOMS", 1)[1].split("\n", 1)[1]
    return [[float(v) for v in line.split()] for line in block.strip().splitlines()]
