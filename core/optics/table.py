"""The look-up table of ring profiles E(r) of a homogeneous half-space over scattering and
absorption, for one refractive index, anisotropy and set of rings (what SFDI's white Monte Carlo
table is for its spatial frequencies).

From a white run in mean free paths (:mod:`.radial`), a medium of scattering ``mus`` and
absorption ``mua`` (per grid step) gives a record of cell ``i`` (mean distance ``rho_i``, path
``L_i``, weight ``W_i``) the lateral distance ``rho_i / mus`` grid steps and the weight
``W_i exp(-a L_i)``, ``a = mua / mus``. The beam enters uniformly over the lit pixel and the camera
averages over a pixel, so a record at lateral displacement ``s`` from the entry point lands in
the pixel of offset ``d`` with probability ``Lambda(s_x - d_x) Lambda(s_y - d_y)`` (the overlap of
two unit squares, ``Lambda(t) = max(0, 1 - |t|)``); averaged over the displacement's azimuth
(uniform: the medium is isotropic about the beam) and over the ring's members ``d`` with their
weights, that is the ring's geometry kernel ``G_r(rho)``::

    E(r; mus, mua) = (1 / N) sum_i W_i exp(-a L_i) G_r(rho_i / mus)

with ``N`` the run's photons: the same quantity, normalisation and rings as the ring light
stack's E_r (the region mean of a laterally homogeneous surface, every ring whole).

The table holds ``log E`` on a regular grid of ``u = log mus`` and ``v = log a`` and interpolates
it by Catmull-Rom splines in both (continuous first derivatives: :mod:`.pixel_fit` differentiates it).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numba
import numpy as np

from ..rings.geometry import ring_geometry
from .radial import FARTHEST_RHO, RadialRun, TableError

ALBEDO_RANGE = (1e-6, 30.0)
"""``a = mua / mus`` the table spans."""
ALBEDO_POINTS = 120
REDUCED_SCATTERING_RANGE = (0.004, 4.0)
"""mus' (per grid step) the table spans, the upper end lowered where the run's records do not reach
the rings' distance (:data:`.radial.FARTHEST_RHO`)."""
SCATTERING_POINTS = 90
KERNEL_STEP = 0.01
"""Grid steps between the samples of each ring's geometry kernel G_r(rho) (linear in between)."""
AZIMUTHS = 256
SMALLEST_LOG = math.log(1e-300)


@dataclass(frozen=True, eq=False)
class ProfileTable:
    """log E(r) over ``u = log mus`` and ``v = log (mua / mus)`` (per grid step).

    Attributes
    ----------
    radii, thickness, antialias
        The rings (grid steps).
    n, g
        Refractive index and anisotropy of the run.
    u0, du, v0, dv
        The grid: ``u_k = u0 + k du``, ``v_j = v0 + j dv``.
    log_profile
        (K, J, R) float64 log E at the grid's nodes.
    photons
        Photons of the white run behind it.
    run
        That run (:mod:`.transform` takes the light beyond the rings from it).
    """

    radii: np.ndarray
    thickness: float
    antialias: bool
    n: float
    g: float
    u0: float
    du: float
    v0: float
    dv: float
    log_profile: np.ndarray
    photons: int
    run: RadialRun | None = None

    @property
    def reduced_scattering_range(self) -> tuple[float, float]:
        """(low, high) mus' per grid step inside the table's interpolation range."""
        scale = 1.0 - self.g
        return (math.exp(self.u0 + self.du) * scale,
                math.exp(self.u0 + (self.log_profile.shape[0] - 2) * self.du) * scale)

    @property
    def absorption_ratio_range(self) -> tuple[float, float]:
        return math.exp(self.v0 + self.dv), math.exp(self.v0 + (self.log_profile.shape[1] - 2) * self.dv)

    def profile(self, musp: float, mua: float) -> np.ndarray:
        """(R,) E(r) of reduced scattering ``musp`` and absorption ``mua`` per grid step
        (interpolated); NaN outside the table (and where either is not a positive number: no
        absorption at all lies outside it too, below its smallest mua / mus)."""
        mus = musp / (1.0 - self.g)
        if not (mus > 0.0 and mua > 0.0 and math.isfinite(mus) and math.isfinite(mua)):
            return np.full(len(self.radii), np.nan)
        values = np.empty(len(self.radii))
        slopes = np.empty((2, len(self.radii)))
        inside = interpolate(self.log_profile, self.u0, self.du, self.v0, self.dv, math.log(mus),
                             math.log(mua / mus), values, slopes)
        return np.exp(values) if inside else np.full(len(self.radii), np.nan)


def kernel_radii(radii, thickness: float) -> float:
    """Largest lateral distance (grid steps) a ring's kernel G_r is nonzero at."""
    return float(np.max(np.asarray(radii, float))) + thickness / 2.0 + 2.0


def ring_kernels(radii, thickness: float = 1.0, antialias: bool = False,
                 ring_weights: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """(R, P) G_r(rho) at ``rho = k * KERNEL_STEP``, k = 0 .. P - 1, and that step: each ring's
    weighted mean over its members of the azimuth-averaged unit-square overlap (module
    docstring). Summed over every offset of the plane the overlaps are 1 at every ``rho``, so a
    ring's value is a mean, as the stack's is. ``ring_weights`` (R, S, S), S odd: each ring's
    weight of offset ``[dy + S // 2, dx + S // 2]`` (rings cut by a region's edge,
    :attr:`ringlight.core.inversion.measured.MeasuredProfile.ring_weights`) instead of whole rings."""
    if ring_weights is None:
        members = [ring_geometry(float(radius), thickness, antialias) for radius in radii]
        members = [(ring.offsets, ring.weights) for ring in members]
        reach = kernel_radii(radii, thickness)
    else:
        half = ring_weights.shape[1] // 2
        members = []
        for weights in ring_weights:
            rows, cols = np.nonzero(weights)
            members.append((np.stack([rows - half, cols - half], 1), weights[rows, cols]))
        reach = max((float(np.hypot(*o.T).max()) for o, _ in members if len(o)), default=0.0) + 2.0
    samples = np.arange(int(math.ceil(reach / KERNEL_STEP)) + 1) * KERNEL_STEP
    rows = []
    for offsets, weights in members:
        if len(offsets) == 0 or weights.sum() <= 0:
            rows.append(np.zeros(len(samples)))
            continue
        # The square's symmetries map members onto classes (|dy|, |dx|) sorted: one overlap each.
        key = np.sort(np.abs(offsets), axis=1)
        classes, inverse = np.unique(key, axis=0, return_inverse=True)
        class_weight = np.bincount(inverse.ravel(), weights, len(classes))
        overlap = _class_overlaps(classes.astype(np.float64), samples, AZIMUTHS)
        rows.append(class_weight @ overlap / weights.sum())
    return np.asarray(rows), KERNEL_STEP


@numba.njit(cache=True)
def _class_overlaps(classes, samples, azimuths):
    """(C, P): for each offset class (a, b), the mean over the azimuth phi of
    Lambda(rho cos phi - a) Lambda(rho sin phi - b) at each ``rho`` of ``samples`` (midpoint rule)."""
    out = np.zeros((classes.shape[0], samples.shape[0]))
    for c in range(classes.shape[0]):
        a = classes[c, 0]
        b = classes[c, 1]
        for p in range(samples.shape[0]):
            rho = samples[p]
            if rho > math.hypot(a, b) + 1.5:
                continue
            total = 0.0
            for k in range(azimuths):
                phi = 2.0 * math.pi * (k + 0.5) / azimuths
                tx = 1.0 - abs(rho * math.cos(phi) - a)
                ty = 1.0 - abs(rho * math.sin(phi) - b)
                if tx > 0.0 and ty > 0.0:
                    total += tx * ty
            out[c, p] = total / azimuths
    return out


def model_profiles(run: RadialRun, kernels: np.ndarray, step: float, mus: np.ndarray,
                   albedo: np.ndarray) -> np.ndarray:
    """(len(mus), len(albedo), R) E(r) for each scattering ``mus`` (per grid step) and each
    ``a = mua / mus``, straight from the run's cells (no interpolation in ``mus`` or ``a``)."""
    used = run.weight.sum(axis=1) > 0
    weight, path = run.weight[used], run.path[used]
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(weight.sum(axis=1) > 0, (run.weight[used] * run.rho[used]).sum(axis=1) / weight.sum(axis=1), 0.0)
    # Per rho cell and albedo: the cell's records' weights after absorption (a, rho) (the rho
    # within a cell varies by RATIO at most, far below the kernels' scale).
    absorbed = np.stack([(weight * np.exp(-a * path)).sum(axis=1) for a in np.atleast_1d(albedo)])
    out = np.empty((len(mus), len(albedo), kernels.shape[0]))
    positions = np.arange(kernels.shape[1]) * step
    for k, scattering in enumerate(np.atleast_1d(mus)):
        distance = rho / scattering
        geometry = np.stack([np.interp(distance, positions, row, right=0.0) for row in kernels])  # (R, I)
        out[k] = absorbed @ geometry.T / run.photons
    return out


def build_table(run: RadialRun, radii, thickness: float = 1.0, antialias: bool = False,
                ring_weights: np.ndarray | None = None) -> ProfileTable:
    """The table of ``run``'s medium for the rings of ``radii`` (grid steps), or of the cut rings
    ``ring_weights`` (as :func:`ring_kernels` takes them)."""
    radii = np.asarray(radii, np.float64)
    kernels, step = ring_kernels(radii, thickness, antialias, ring_weights)
    scale = 1.0 - run.g
    low, high = REDUCED_SCATTERING_RANGE
    high = min(high, FARTHEST_RHO * scale / (kernels.shape[1] * step))
    u = np.linspace(math.log(low / scale), math.log(high / scale), SCATTERING_POINTS)
    v = np.linspace(math.log(ALBEDO_RANGE[0]), math.log(ALBEDO_RANGE[1]), ALBEDO_POINTS)
    profiles = model_profiles(run, kernels, step, np.exp(u), np.exp(v))
    with np.errstate(divide="ignore"):
        log_profile = np.maximum(np.log(profiles), SMALLEST_LOG)
    return ProfileTable(radii, float(thickness), bool(antialias), run.n, run.g, float(u[0]), float(u[1] - u[0]),
                        float(v[0]), float(v[1] - v[0]), log_profile, run.photons, run)


@numba.njit(cache=True, inline="always")
def catmull_rom(t):
    """Weights of the four nodes around ``t`` in [0, 1] and their derivatives by ``t``."""
    t2 = t * t
    t3 = t2 * t
    w0 = 0.5 * (-t3 + 2.0 * t2 - t)
    w1 = 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0)
    w2 = 0.5 * (-3.0 * t3 + 4.0 * t2 + t)
    w3 = 0.5 * (t3 - t2)
    d0 = 0.5 * (-3.0 * t2 + 4.0 * t - 1.0)
    d1 = 0.5 * (9.0 * t2 - 10.0 * t)
    d2 = 0.5 * (-9.0 * t2 + 8.0 * t + 1.0)
    d3 = 0.5 * (3.0 * t2 - 2.0 * t)
    return w0, w1, w2, w3, d0, d1, d2, d3


@numba.njit(cache=True)
def interpolate(log_profile, u0, du, v0, dv, u, v, values, slopes):
    """log E (R,) into ``values`` and its derivatives by u and v (2, R) into ``slopes`` at
    ``(u, v)``; False (and nothing written) outside the nodes a spline can use. Each derivative's
    rings are contiguous (with an (R, 2) layout a look-up took 0.156 us, 0.121 us with this one, in
    one run on a loaded machine)."""
    su = (u - u0) / du
    sv = (v - v0) / dv
    k = int(math.floor(su))
    j = int(math.floor(sv))
    if k < 1 or j < 1 or k > log_profile.shape[0] - 3 or j > log_profile.shape[1] - 3:
        return False
    wu = catmull_rom(su - k)
    wv = catmull_rom(sv - j)
    for r in range(log_profile.shape[2]):
        value = 0.0
        slope_u = 0.0
        slope_v = 0.0
        for a in range(4):
            row = 0.0
            row_v = 0.0
            for b in range(4):
                node = log_profile[k - 1 + a, j - 1 + b, r]
                row += wv[b] * node
                row_v += wv[4 + b] * node
            value += wu[a] * row
            slope_u += wu[4 + a] * row
            slope_v += wu[a] * row_v
        values[r] = value
        slopes[0, r] = slope_u / du
        slopes[1, r] = slope_v / dv
    return True


DEFAULT_PHOTONS = 1_000_000
"""Photons of the white run behind a table: its noise is 0.03-0.3 % of E per ring (0.1-1 % at
10^5 photons over four seeds), which put mu_a 4 % off at 4 * 10^4 photons and within 0.5 % at
4 * 10^5 on a slab of mus' 0.1, mua 0.01 per grid step; the run takes about 50 s on two busy
cores for g = 0 (longer as g nears 1), once per n and g (then read from the user cache)."""
PHOTON_RANGE = (10_000, 100_000_000)
"""Photons of a table's white run that :func:`table_for` takes (:func:`check_photons`), and so the
maps, a region's fit, a calibration, a model profile and R_d maps. Below the range the table is
noise: against a run of 10^6 photons, the profile of 8 rings (radii 0-7, mus' 0.1-1 and mua
0.001-0.1 per grid step, n 1.4) was off by 2-13 % rms per ring at 10^3 photons (up to 22 %),
0.9-4.6 % at 10^4, 0.2-1.3 % at 4 * 10^4 and 0.1-0.7 % at 10^5, where the maps' standard errors
allow 0.5 % (:data:`.maps.MODEL_FLOOR`); a run of 0 photons traced 16 and gave maps 37 % off in
mu_s' on skin1 without a word. Above it a run takes hours on a CPU (about 50 s per 10^6 photons on
two cores)."""
_TABLES: dict[tuple, ProfileTable] = {}
_KEPT_TABLES = 8


def check_photons(photons: int) -> int:
    """``photons`` (an int within :data:`PHOTON_RANGE`) for a table a user asks for; TableError
    naming the range otherwise."""
    low, high = PHOTON_RANGE
    if isinstance(photons, bool) or not isinstance(photons, (int, np.integer)) or not low <= photons <= high:
        raise TableError(f"photons of the white run must be a whole number from {low} to {high}, got {photons}")
    return int(photons)


def table_for(n: float, g: float, radii, thickness: float = 1.0, antialias: bool = False,
              photons: int = DEFAULT_PHOTONS, seed: int = 0, use_cache: bool = True, progress=None,
              ring_weights: np.ndarray | None = None) -> ProfileTable:
    """The table of a half-space of index ``n`` and anisotropy ``g`` for these rings: its white run
    from the user cache or traced (:func:`.radial.radial_run`), the table from the user cache
    beside it or built (:mod:`.table_cache`), and kept in memory for the next call with the same
    arguments. ``use_cache=False`` traces and builds without reading or writing either.
    ``progress(fraction)`` while tracing (may raise Cancelled); ``ring_weights`` as
    :func:`build_table` takes them. ``photons`` outside :data:`PHOTON_RANGE` is a TableError
    (:func:`check_photons`), for every function that makes its table here."""
    from .radial import radial_run
    from .table_cache import kept_table  # which builds tables with this module's build_table

    check_photons(photons)
    radii = np.asarray(radii, np.float64)
    cut = None if ring_weights is None else hashlib.sha256(np.ascontiguousarray(ring_weights, np.float64)).hexdigest()
    key = (float(n), float(g), tuple(radii.tolist()), float(thickness), bool(antialias), int(photons), int(seed), cut)
    if use_cache and key in _TABLES:
        return _TABLES[key]
    run = radial_run(n, g, photons, seed, use_cache, progress)
    if not use_cache:
        return build_table(run, radii, thickness, antialias, ring_weights)
    table = kept_table(run, radii, thickness, antialias, ring_weights, photons, seed, cut)
    while len(_TABLES) >= _KEPT_TABLES:
        _TABLES.pop(next(iter(_TABLES)))
    _TABLES[key] = table
    return table
