r"""Per-segment irradiance: one vectorised Dr.Jit pass over all requested segments.

For each requested segment, K points are drawn uniformly (by area) on its mesh faces. Leaf
blades are evaluated on both sides at every point, stems and sheaths on their outer side. On a
side with unit normal n at point x:

.. math::

    E_{sun} = \cos^+(n, \omega_\odot)\,V(x, \omega_\odot) + \pi L_\odot(x, \omega), \qquad
    E_{sky} = \pi L_{sky}(x, \omega), \qquad \omega \sim \cos\theta/\pi

The direct sun comes from an explicit shadow ray. :math:`L_\odot, L_{sky}` are the sun and sky
radiance arriving along the cosine-sampled ray ω, from a path tracer over the plant mesh
(Mitsuba ray casting, the leaf BSDF) and the analytic soil, sun and sky of
:class:`~lightfit.light.scene.FieldScene`: at each of up to ``bounces`` scattering vertices the
sun is added by next-event estimation with a shadow ray, the next direction is drawn from the
BSDF, and a path leaving upwards collects sky radiance. Absorbed light uses the leaf's
absorptance for the direction the light comes from, :math:`a(\omega) = 1 - \rho(\omega)`, with
the directional albedo ρ from a tabulated GGX albedo (:func:`~lightfit.light.bsdf.leaf_albedo`:
deterministic, so absorbed light is never negative). Values are per unit one-sided
area, summed over the two sides of a blade, in units of the sun's DNI (sun part) and of the
sky's horizontal DHI (sky part).

Gradients (AD mode: reverse) with respect to specular, roughness and subsurface use the
estimator of path replay backpropagation (PRB, Vicini et al. 2021): sampling is detached and
the BSDF weights f/pdf carry the derivative (pdf detached). Paths here are short (a few
bounces), so instead of replaying them the whole unrolled computation is kept in Dr.Jit's AD
graph and differentiated once; memory grows with samples × bounces.

In a periodic scene (``FieldScene(..., cell=...)``) every ray above — the first cosine-sampled
ray, each scattered segment, the direct-sun and next-event shadow rays — is cast through
:class:`~lightfit.light.periodic.PeriodicTracer`, which wraps it through the cell's side faces;
points on faces overhanging the cell are first moved into it. Finite scenes take the original
code path unchanged.

A primal render is split into the paths' geometry (points, cosine-sampled first rays, every
scattered segment and the BSDF samples along them: the directions come from the BSDF's frozen
sampling, so they depend on neither the sun nor the leaf parameters), the sun's shadow rays
(direct sun and next-event rays from the path vertices: the sun only), and the weights (path
throughputs, BSDF values towards the sun, absorptances: the leaf parameters). The geometry is
traced once and kept (:meth:`SegmentEstimator._geometry`), so the time steps of a day each cast
only the sun's rays, and :meth:`SegmentEstimator.render_many` weighs the same geometry and shadow
rays at many leaf-parameter points without casting a ray (the emulator's design). Values are
bitwise those of a fresh estimator.

All random numbers — points, directions, BSDF samples along the path — are keyed by (seed,
segment id, sample index), so a segment's values do not depend on which other segments are
requested or how the field is partitioned.

``direct="projection"`` (periodic scenes) takes the unscattered light — the direct sun and the
sky seen directly — and, with ``bounces`` ≥ 1, the light scattered once by a leaf or the soil
from rays cast down over the whole cell instead (:mod:`lightfit.light.projection`): the paths
then carry only the rest, light scattered twice and more (no direct-sun shadow ray at the point,
no sky where the first ray escapes, no sun or sky through their first vertex), and the two
independent estimates are added replicate by replicate. Same expectation, a fraction of the
variance (docs/light-sampling.md, "Direct light by projection").
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from lightfit.defaults import (
    DARK_FLOOR,
    DEFAULT_RAYS_PER_M2,
    MAX_ADAPTIVE_SAMPLES,
    MAX_BOUNCES_FOR_TOLERANCE,
    MIN_PILOT,
)
from lightfit.errors import InputError, check_integer, check_real, is_real
from lightfit.light import projection
from lightfit.light.backend import owned, sum_float64
from lightfit.light.bsdf import LEAF_PARAMETERS, leaf_albedo, lobe_weights
from lightfit.light.keyed_random import check_seed, hash32, keyed_uniforms
from lightfit.light.projection import DirectProjection
from lightfit.light.scene import RAY_OFFSET_M, FieldScene, Optics

PARTS = ("incident_sun", "incident_sky", "absorbed_sun", "absorbed_sky")
#: DHI / DNI of a clear day: how the sun and sky parts are weighted where a relative error is judged
#: without the step's weather (the adaptive allocation's default, the SE reports).
CLEAR_DAY_DHI_PER_DNI = 0.3
#: Where a :class:`SegmentEstimator`'s unscattered light comes from (its ``direct`` argument).
DIRECT_MODES = ("paths", "projection", "none")
#: Version of the estimator's random numbers and sampling: bumped whenever a change moves rendered
#: values (not only their rounding), so that renders kept on disk (emulator designs, keyed by
#: :func:`lightfit.model.emulator.render_key`) from before the change are not reused with renders
#: from after it. 2: low-dimensional Kronecker sequences for the point and first directions.
#: 3: the albedo table Catmull–Rom in roughness (:func:`~lightfit.light.bsdf.leaf_albedo`; values
#: between the table's nodes move by at most F0 × 2.5e-3 ≤ 2e-4 of the albedo). 4: each plant's
#: stem and sheath prisms turned about their axes by its own angle (:func:`lightfit.plant.mesh.prism_turn`;
#: the mesh, not the sampling, but the segment table that keys the geometry is unchanged).
#: 5: the GGX albedo table by quadrature instead of Monte Carlo (:func:`~lightfit.light.bsdf._compute_table`;
#: the glossy lobe's albedo moves by up to 8e-3, the leaf's by F0 × that ≤ 7e-4).
ESTIMATOR_VERSION = 5
# Random dimensions: 0–2 point on the segment; per side 8 (front 3–10, back 11–18), of which the
# first 2 draw the direction and the other 6 are unused since absorptance became a tabulated
# albedo (kept in the numbering, never generated); then 3 per scattering order and side.
_N_FIXED_DIMS = 19
_USED_PER_SIDE = 2
_DIMS_PER_BOUNCE = 3
# Which dimensions are low-discrepancy. A Kronecker sequence R_d in many dimensions has
# generators α_i = φ_d^{-(i+1)} all close to 1 (0.98, 0.96, … for the 37 dimensions of 3
# bounces), so the first few points of a replicate lie on a short line (8 points spanned 0.15 of
# dimension 0): the points and first directions of a replicate were clustered, not spread. The
# dimensions that matter most, the point (0–2) and the first direction of each side (3–4, 11–12),
# are therefore Kronecker sequences of their own low dimension (R_5 and R_2); the scattering
# dimensions are independent uniforms hashed from (replicate shift, point index).
_QMC_FRONT = (0, 1, 2, 3, 4)
_QMC_BACK = (11, 12)
# The first directions' sequence {Δ + j·α} is computed in float32, where j·α keeps only
# 24 bits: from j = 2¹⁷ on its rounding (2⁻⁷) wiped out the shift Δ's bits below it, so the
# coordinate took 128 values (a biased Riemann sum; 16 at j = 2²⁰, one at j = 2²⁴ − 8: every
# path started in the same direction). From this j on, j·α mod 1 is taken in 32-bit fixed point
# instead; below it (up to 1023: every adaptive and default render) the float32 values as before.
_FLOAT32_J = 2**10


def _side_dims(bounces: int) -> tuple[list[int], list[int]]:
    """The random dimensions each side's path reads, in order: its first direction, then 3 per
    scattering order (front, back)."""
    nb = _DIMS_PER_BOUNCE * bounces
    front = [*range(3, 3 + _USED_PER_SIDE), *range(_N_FIXED_DIMS, _N_FIXED_DIMS + nb)]
    back = [*range(11, 11 + _USED_PER_SIDE), *range(_N_FIXED_DIMS + nb, _N_FIXED_DIMS + 2 * nb)]
    return front, back


def _used_dims(bounces: int) -> np.ndarray:
    """The random dimensions the estimator reads: the point and both sides' paths (the others of
    the numbering are never generated)."""
    front, back = _side_dims(bounces)
    return np.array([0, 1, 2, *front, *back])


def sequence_alpha(n_dims: int) -> np.ndarray:
    """Kronecker generator per random dimension of :class:`SegmentEstimator` (NaN: hashed)."""
    alpha = np.full(n_dims, np.nan)
    alpha[list(_QMC_FRONT)] = kronecker_alpha(len(_QMC_FRONT))
    alpha[list(_QMC_BACK)] = kronecker_alpha(len(_QMC_BACK))
    return alpha


def replicates_for(samples: int) -> int:
    """Independent randomised replicates R used for the standard error (8 from K = 32 on)."""
    return 8 if samples >= 32 else max(2, samples // 4)


def kronecker_alpha(n_dims: int) -> np.ndarray:
    r"""Generator of the :math:`R_d` low-discrepancy sequence (Roberts 2018): α_i = φ_d^{-(i+1)}
    with φ_d the positive root of :math:`x^{d+1} = x + 1`."""
    phi = 2.0
    for _ in range(60):
        phi = (1.0 + phi) ** (1.0 / (n_dims + 1))
    return np.mod(phi ** -np.arange(1.0, n_dims + 1.0), 1.0)


def checked_segment_ids(segment_ids: ArrayLike) -> np.ndarray:
    """``segment_ids`` as int64, or :class:`InputError` unless they are integers, at least one, each
    once and in increasing order: results come one per segment in that order, and ids sorted or
    merged unsaid (as they were) would misalign a caller's own arrays (weights, cotangents) with them."""
    a = np.asarray(segment_ids)
    if a.dtype == object:  # e.g. pandas' nullable Int64: whole Python ints, or refused below
        try:
            a = np.array([operator.index(v) for v in a.ravel()], dtype=np.int64).reshape(a.shape)
        except TypeError:
            pass
    if a.ndim != 1 or a.size == 0:
        raise InputError(
            f"no segments to render (segment_ids of shape {a.shape})",
            parameter="segment_ids",
            expected="a 1-D array of at least one segment id",
        )
    # whole floats only in float64 below 2⁵³ (float32 holds ids as large as 10⁶·plant only rounded)
    whole = a.dtype == np.float64 and np.all(np.isfinite(a) & (a == np.round(a)) & (np.abs(a) < 2.0**53))
    if a.dtype.kind not in "iu" and not whole:
        raise InputError(f"segment_ids of dtype {a.dtype}", parameter="segment_ids", expected="integer segment ids")
    seg = a.astype(np.int64)
    step = np.diff(seg)
    if (step <= 0).any():
        i = int(np.flatnonzero(step <= 0)[0]) + 1
        raise InputError(
            f"segment_ids[{i}] = {seg[i]} {'repeats' if step[i - 1] == 0 else 'comes after'} {seg[i - 1]}",
            parameter="segment_ids",
            expected="each id once, in increasing order (results come in that order: np.unique(ids) sorts them)",
        )
    return seg


@dataclass
class Irradiance:
    """Per-segment irradiance, per unit DNI (sun parts) and per unit DHI (sky parts).

    All arrays have one entry per requested segment, in ``segment_id`` order. ``se[part]``
    is the Monte Carlo standard error of ``part`` (:data:`PARTS`). Multiply by PAR DNI / DHI (µmol m⁻² s⁻¹) to get PAR
    per unit one-sided leaf (or stem lateral) area. In a periodic scene ``meta["periodic"]``
    reports the crossing cap and, per kind of ray, the rays cast, side crossings made and rays
    stopped by the cap (:meth:`SegmentEstimator.render`).
    """

    segment_id: np.ndarray
    incident_sun: np.ndarray
    incident_sky: np.ndarray
    absorbed_sun: np.ndarray
    absorbed_sky: np.ndarray
    se: dict[str, np.ndarray]
    samples: int
    bounces: int
    seed: int
    sun_vector: np.ndarray
    meta: dict = field(default_factory=dict)
    #: ``cov[part]``: covariance of the sun and sky parts' estimates (``part`` "incident" or
    #: "absorbed"), same units as ``se²``. They share points and paths: a first ray that escapes
    #: brings sky and no scattered sun, one that hits a leaf the reverse, so the covariance is
    #: mostly negative and treating the parts as independent overstates the total's error.
    cov: dict = field(default_factory=dict)

    def total(self, part: str, dni: float, dhi: float) -> np.ndarray:
        """``dni·<part>_sun + dhi·<part>_sky`` for ``part`` in {"incident", "absorbed"}: the parts are per
        unit DNI and DHI, so the result is in the units of ``dni`` and ``dhi`` (e.g. µmol m⁻² s⁻¹ of
        PAR) per one-sided segment area."""
        return dni * getattr(self, f"{part}_sun") + dhi * getattr(self, f"{part}_sky")

    def front(self, part: str) -> np.ndarray:
        """``part`` on the front side only (blades: the upper side; stems: the outer side)."""
        return self.meta["front"][part]

    def total_se(self, part: str = "absorbed", dni: float = 1.0, dhi: float = CLEAR_DAY_DHI_PER_DNI) -> np.ndarray:
        """Standard error of ``total(part, dni, dhi)``, in its units, with the sun–sky covariance
        (:attr:`cov`; parts treated as independent where it is missing)."""
        var = (dni * self.se[f"{part}_sun"]) ** 2 + (dhi * self.se[f"{part}_sky"]) ** 2
        return np.sqrt(np.maximum(var + 2 * dni * dhi * self.cov.get(part, 0.0), 0.0))

    def relative_se(self, part: str = "absorbed", dni: float = 1.0, dhi: float = CLEAR_DAY_DHI_PER_DNI) -> np.ndarray:
        """:meth:`total_se` ÷ |``total(part, dni, dhi)``| (inf where the total is 0)."""
        v = self.total(part, dni, dhi)
        return np.divide(self.total_se(part, dni, dhi), np.abs(v), out=np.full_like(v, np.inf), where=v != 0)


def samples_used(samples: int) -> int:
    """The K a render takes for a requested K: :func:`replicates_for` R replicates of ⌈K / R⌉
    points each (K rounded up to a multiple of R)."""
    r = replicates_for(int(samples))
    return r * -(-int(samples) // r)


#: The light library's defaults for a scene that says nothing: K points per segment and scattering
#: orders (3 serve a finite field's bright soil and any leaf; the coupled model resolves its own from
#: the leaf, docs/light.md "Recommended settings").
DEFAULT_SAMPLES = 64
DEFAULT_BOUNCES = 3


def adaptive_pilot(samples: int) -> int:
    """Points per segment of adaptive sampling's first round for a run's ``samples``."""
    return max(int(samples), MIN_PILOT)


def check_samples(value, *, exact: bool = False) -> int:
    """Points per segment K: an integer ≥ 2 (the standard error needs two). ``exact``: also one
    that a render takes as it is (:func:`samples_used`), for settings that are recorded with the
    results, so that the K reported is the K rendered."""
    k = check_integer(value, "samples", 2, why="needed for a standard error")
    if exact and samples_used(k) != k:
        below = k // 8 * 8 if k >= 40 else max(j for j in range(2, k) if samples_used(j) == j)
        raise InputError(
            f"samples={k}",
            parameter="samples",
            expected=f"a K of {replicates_for(k)} replicates × equal points, which {k} is not: e.g. {below} or "
            f"{samples_used(k)} (8, 16, 32, 64, … always are)",
        )
    return k


#: Most evaluations (points × sides) a render holds: Dr.Jit's arrays have at most 2³² entries, as
#: the projection's rays of a kind (:data:`~lightfit.light.projection.MAX_RAYS_PER_KIND`).
MAX_EVALUATIONS = projection.MAX_RAYS_PER_KIND - 1
#: Most points per replicate: a point's index in its replicate's sequence is exact in float32.
MAX_PER_REPLICATE = 2**24


def check_samples_fit(samples: int, n_segments: int) -> int:
    """``samples`` (K, :func:`check_samples`) if a render of ``n_segments`` segments can hold it: at
    most 2 × S × K evaluations (a blade's points on both sides) within :data:`MAX_EVALUATIONS`, and
    at most :data:`MAX_PER_REPLICATE` points per replicate; else :class:`InputError` naming
    ``samples`` and the largest K that fits (10⁸ ended in a Dr.Jit error about arrays past 2³²)."""
    k = check_samples(samples)
    r = replicates_for(k)
    fits = min(MAX_EVALUATIONS // (2 * max(int(n_segments), 1)), 8 * MAX_PER_REPLICATE)
    if samples_used(k) > fits:
        largest = fits // replicates_for(fits) * replicates_for(fits)
        raise InputError(
            f"samples={k} for {n_segments} segment(s): {samples_used(k) // r} points in each of {r} replicates",
            parameter="samples",
            expected=f"at most {largest} samples per segment here (a render holds 2 × segments × samples "
            f"evaluations, both sides of a blade, in arrays of at most 2³² entries, and at most 2²⁴ points "
            "per replicate)",
        )
    return k


def check_run_samples(value, target_rse: float | None) -> int:
    """A run's ``samples`` (:func:`check_samples`) that it also renders as given: the fixed K, or
    with a target the adaptive pilot (:func:`adaptive_pilot`), so the K recorded is the K rendered;
    with a target also a pilot no larger than the cap :data:`MAX_ADAPTIVE_SAMPLES` (refused after
    the plants had grown, naming ``max_samples``, which no command-line option sets)."""
    k = check_samples(value)
    if target_rse is not None and k > MAX_ADAPTIVE_SAMPLES:
        raise InputError(
            f"samples={k} with target_rse={target_rse!r}",
            parameter="samples",
            expected=f"with a target, the pilot count per segment: at most the adaptive cap of {MAX_ADAPTIVE_SAMPLES}",
        )
    check_samples(k if target_rse is None else adaptive_pilot(k), exact=True)
    return k


def check_bounces(value) -> int:
    """Scattering orders traced: an integer in [0, :data:`MAX_BOUNCES_FOR_TOLERANCE`]. More orders than
    :func:`bounces_for_tolerance` ever hands out add nothing a leaf or soil can scatter (64 keep the
    truncated light near 1 % even at an albedo of 0.9) while memory grows with samples × bounces:
    10⁴ was accepted and ran out of memory instead."""
    return check_integer(
        value,
        "bounces",
        0,
        high=MAX_BOUNCES_FOR_TOLERANCE + 1,
        expected=f"an integer in [0, {MAX_BOUNCES_FOR_TOLERANCE}]: at most {MAX_BOUNCES_FOR_TOLERANCE} scattering "
        "orders, which leave out under 1.1 % of the light even at an albedo of 0.9 (a PAR leaf's is ≈ 0.2); "
        "memory grows with samples × bounces",
    )


def check_target_rse(value) -> float:
    """A per-segment relative standard error to reach (adaptive sampling): a number in (0, 1)."""
    return check_real(
        value, "target_rse", 0, 1, open_lo=True, open_hi=True, expected="a relative standard error in (0, 1)"
    )


def check_direct_light(field_scene: FieldScene, direct: str, rays_per_m2, replicates: int = 8) -> None:
    """A user's choice of the segments' unscattered light: ``"paths"``, or ``"projection"`` on a
    periodic scene with valid rays per m² (:func:`~lightfit.light.projection.check_rays`), no more
    of a kind than the projection can number over the scene's cell with ``replicates``
    (:func:`~lightfit.light.projection.ray_grids`); checked before anything renders."""
    if direct not in DIRECT_MODES[:2]:
        raise InputError(f"direct={direct!r}", parameter="direct", expected="'paths' or 'projection'")
    if direct == "projection":
        projection.check_periodic(field_scene)
        projection.ray_grids(field_scene.cell, projection.check_rays(rays_per_m2), replicates)


def check_par_weights(dni, dhi) -> tuple[float, float]:
    """The weights of the sun and sky parts in an absorbed PAR whose error is judged (DNI and DHI,
    any one unit): finite, ≥ 0 and not both 0 (nothing to judge)."""
    if not (is_real(dni) and is_real(dhi) and math.isfinite(dni) and math.isfinite(dhi) and dni >= 0 and dhi >= 0):
        raise InputError(f"dni={dni!r}, dhi={dhi!r}", parameter="dni, dhi", expected="finite numbers ≥ 0")
    if dni + dhi == 0:
        raise InputError("dni=0 and dhi=0", parameter="dni, dhi", expected="some light to weigh the error by")
    return float(dni), float(dhi)


def check_dark_floor(value) -> float:
    """Adaptive sampling's light floor: a fraction of the PAR above the canopy in [0, 1)."""
    return check_real(
        value, "dark_floor", 0, 1, open_hi=True, expected="a fraction of the PAR above the canopy in [0, 1)"
    )


#: Largest ray origin offset ``epsilon_m`` (m) a render accepts: stems are 1.5 mm in radius and a
#: sheath wraps its culm 0.3–0.9 mm away, so larger offsets step over organs.
MAX_EPSILON_M = 1e-3


def _albedo_bound(optics: Optics) -> float:
    """The larger of the leaf's albedo bound F_0 + (1 − F_0)c (its lobes' weights summed) and the soil's."""
    return max(sum(lobe_weights(optics.specular, optics.subsurface, optics.base_color)), optics.soil_albedo, 1e-6)


def truncation_bound(bounces: int, optics: Optics) -> float:
    r"""Bound on the light that ``bounces`` scattering orders leave out, relative to the unscattered
    light (order 0): :math:`\rho^{b+1}/(1-\rho)` (:func:`bounces_for_tolerance`); ``inf`` for ρ ≥ 1."""
    rho = _albedo_bound(optics)
    return rho ** (bounces + 1) / (1 - rho) if rho < 1 else math.inf


def bounces_for_tolerance(tolerance: float, optics: Optics) -> int:
    r"""Scattering orders needed so that the truncated light is below ``tolerance`` (relative).

    With leaf albedo ρ ≤ F_0 + (1 − F_0)c per scattering (the lobes' weights summed), the light
    left after b orders is at most :math:`\rho^{b+1}/(1-\rho)` of the unscattered light; a
    conservative bound (light escaping the canopy only shortens the series). More than
    :data:`MAX_BOUNCES_FOR_TOLERANCE` orders (ρ near 1, where the series barely converges, or ρ ≥ 1,
    where it does not) is refused: give ``bounces`` yourself.
    """
    check_real(tolerance, "tolerance", 0, 1, open_lo=True, open_hi=True, expected="a number in (0, 1)")
    rho = _albedo_bound(optics)
    b = (
        max(0, math.ceil(math.log(tolerance * (1 - rho)) / math.log(rho)) - 1)
        if rho < 1
        else MAX_BOUNCES_FOR_TOLERANCE + 1
    )
    if b > MAX_BOUNCES_FOR_TOLERANCE:
        raise InputError(
            f"an albedo of {rho:.4g} (leaf or soil) needs more than {MAX_BOUNCES_FOR_TOLERANCE} scattering orders for "
            f"tolerance={tolerance!r}",
            parameter="bounces",
            expected="bounces given explicitly, or leaf and soil albedos below 1",
        )
    return b


class SegmentEstimator:
    """Irradiance on requested segments of a :class:`FieldScene`.

    Args:
        field_scene: the scene (mesh, optics, sun).
        segment_ids: segments to measure (e.g. the measurement area's), integers in increasing
            order, each once (:func:`checked_segment_ids`: results come in that order); each must
            have faces.
        samples: K, points per segment (blades: each point on both sides), rounded up to a
            multiple of the replicate count R (:func:`replicates_for`); points are randomised
            quasi-Monte Carlo: in replicate r of a segment, the point and the first direction of
            each side are Kronecker sequences {Δ + j·α} (:func:`sequence_alpha`) with a random
            shift Δ keyed by (seed, segment id, r), the scattering dimensions uniforms hashed from
            Δ and j; replicates are independent, and the standard error comes from the spread of
            the R replicate means.
        bounces: the most scattering events a path includes (0: unscattered light only, the direct
            sun and the directly visible sky).
        seed: random seed; same seed, same result.
        epsilon_m: ray origin offset along the side normal at the paths' points and vertices, m (the
            projection's continued rays keep :data:`~lightfit.light.scene.RAY_OFFSET_M`).
        first: index of the first point taken from each replicate's sequence (default 0): an
            estimator with ``first = M`` continues one with M points per replicate
            (:func:`render_adaptive` adds samples in rounds this way).
        direct: where the unscattered light comes from: ``"paths"`` (each point's shadow ray to
            the sun and its first ray escaping to the sky), ``"projection"`` (periodic scenes:
            rays cast down over the cell, :class:`~lightfit.light.projection.DirectProjection`)
            or ``"none"`` (what the paths carry alongside a projection: light scattered twice
            and more).
        direct_rays_per_m2: ``direct="projection"``: rays per m² of ground, ``(sun, sky)`` or
            one number for both (the projection's accuracy knob; its cost does not grow with
            the number of segments requested; the sun's rays are cast once per sun and kept
            within ``projection.SUN_HITS_BUDGET_BYTES``, the sky's once).
    """

    def __init__(
        self,
        field_scene: FieldScene,
        segment_ids: ArrayLike,
        *,
        samples: int = DEFAULT_SAMPLES,
        bounces: int = DEFAULT_BOUNCES,
        seed: int = 0,
        epsilon_m: float = RAY_OFFSET_M,
        first: int = 0,
        direct: str = "paths",
        direct_rays_per_m2: float | tuple[float, float] = DEFAULT_RAYS_PER_M2,
    ):
        check_samples(samples)
        check_bounces(bounces)
        check_seed(seed)
        check_real(
            epsilon_m,
            "epsilon_m",
            0,
            MAX_EPSILON_M,
            open_lo=True,
            expected=f"a ray offset in metres in (0, {MAX_EPSILON_M:g}]: organs are millimetres thick",
        )
        if direct not in DIRECT_MODES:
            raise InputError(f"direct={direct!r}", parameter="direct", expected=" or ".join(map(repr, DIRECT_MODES)))
        if direct == "projection" and first != 0:  # render_adaptive: rounds with "none", one projection
            raise InputError(
                f"first={first!r} with direct='projection'",
                parameter="first",
                expected="first=0: the projection is the whole of the direct light, not a continuation",
            )
        self.fs, self.bounces, self.seed = field_scene, int(bounces), int(seed)
        check_samples_fit(samples, len(checked_segment_ids(segment_ids)))
        self.samples = samples_used(samples)  # K rounded up to R·M
        self.replicates = replicates_for(int(samples))
        self.per_replicate = self.samples // self.replicates
        seg = checked_segment_ids(segment_ids)
        self.segment_id = seg
        K, R = self.samples, self.replicates
        self._n_dims = _N_FIXED_DIMS + 2 * _DIMS_PER_BOUNCE * self.bounces
        keys = (seg[:, None].astype(np.uint64) << np.uint64(8)) + np.arange(R, dtype=np.uint64)[None, :]
        # (S, R, used dimensions): one random shift per replicate, for the dimensions the paths read
        used = _used_dims(self.bounces)
        self._shift = keyed_uniforms(self.seed, keys, used)
        self._column_of = {int(d): i for i, d in enumerate(used)}  # dimension → column of _shift
        self._alpha = sequence_alpha(self._n_dims)
        # j = first + point index within a replicate is exact in float32 (the sequences' columns).
        if not isinstance(first, (int, np.integer)) or not 0 <= first <= 2**24 - self.per_replicate:
            raise InputError(
                f"first={first!r}", parameter="first", expected=f"an integer in [0, {2**24 - self.per_replicate}]"
            )
        self.first = int(first)
        self.epsilon_m = float(epsilon_m)
        self.area_m2 = self._layout(seg)
        # Evaluations: every point's front side in (segment, point) order, then the back side of
        # every point on a blade face, in the same order: ``_back_of`` is the front index of each.
        import drjit as dr

        # Dims 0–2, (S·R, 3), in float64 for the points.
        point_columns = [self._column_of[d] for d in range(3)]
        self._point_shift = owned(self._shift[:, :, point_columns].reshape(-1), self.fs.mi.Float64)
        front = dr.arange(self.fs.mi.UInt32, len(seg) * K)
        blade = self._place(*self._point_coordinates(front))[2]
        self._back_of_dr = dr.compress(blade)  # read by _evaluations (render and vjp)
        self._back_of = np.asarray(self._back_of_dr, dtype=np.int64)
        self.n_evaluations = len(seg) * K + len(self._back_of)
        self.is_blade = np.zeros(len(seg), bool)
        self.is_blade[self._back_of // K] = True
        self._wrap_log: list = []  # periodic rays cast (kind, active, capped, crossings), see render()
        # Periodic walks fused into the render's kernel (primal) or evaluated apart (vjp).
        self._fuse = False
        self._kept = None  # (key, geometry, ray counts) of _geometry
        #: _sun_key() → (shadow rays, ray counts) of the suns rendered, most recently used last
        self._suns_kept: dict = {}
        self.direct = direct
        self._scattered_only = direct != "paths"
        self._direct = (
            DirectProjection(
                self.fs,
                seg,
                self.area_m2,
                replicates=R,
                seed=self.seed,
                rays_per_m2=direct_rays_per_m2,
                bounces=self.bounces,
            )
            if direct == "projection"
            else None
        )

    def _layout(self, seg: np.ndarray) -> np.ndarray:
        """Prepare :meth:`_place` for the requested ids; returns the one-sided area of each, m².

        One of the two hooks for where an estimator measures, with :meth:`_place`
        (:class:`lightfit.light.sensors.SensorEstimator` overrides both with sensor lines; the
        tracing is shared)."""
        area, self._ranges = self.fs.face_sampler.ranges(seg)
        return area

    def _place(self, si, u):
        """Points of the requested ids from their quasi-random coordinates (Dr.Jit).

        ``si`` (UInt32): the point's index among the requested ids; ``u``: its three Float64
        coordinates in [0, 1). Here dim 0 picks a face by area and dims 1–2 a uniform point on it
        (:class:`~lightfit.light.face_sampling.FaceSampler`). Returns ``(x, n, blade)``: the point
        (m) and the unit normal of its front side (three Float64 each; zero for a zero-area face:
        only a segment made entirely of them can pick one, and its evaluations are masked out)
        and whether it also has a back side.
        """
        return self.fs.face_sampler.place(self._ranges, si, u)

    def _replicate_index(self, f):
        """Of front points ``f`` (UInt32: segment index × K + point index): their replicate's row
        in the (S·R, used dimensions) shifts, and their index j in the replicate's sequence
        (``first`` + point index within the replicate); both UInt32."""
        import drjit as dr

        mi = self.fs.mi
        K, M = dr.opaque(mi.UInt32, self.samples), dr.opaque(mi.UInt32, self.per_replicate)
        pt = f % K
        return (f // K) * dr.opaque(mi.UInt32, self.replicates) + pt // M, pt % M + dr.opaque(mi.UInt32, self.first)

    def _point_coordinates(self, f):
        """``(si, u)`` of front points ``f``: their index among the requested ids and their
        coordinates {Δ + j·α} of dims 0–2 (Float64, as the shifts are)."""
        import drjit as dr

        mi = self.fs.mi
        row, j = self._replicate_index(f)
        j = mi.Float64(j)
        u = []
        for dim in range(3):
            v = dr.gather(mi.Float64, self._point_shift, row * 3 + dim) + j * float(self._alpha[dim])
            u.append(v - dr.floor(v))
        return f // dr.opaque(mi.UInt32, self.samples), u

    def _evaluations(self):
        """Per evaluation (Dr.Jit): ``(f, back)``, the index of its point among the fronts and
        whether it is that point's back side."""
        import drjit as dr

        mi = self.fs.mi
        n_front = len(self.segment_id) * self.samples
        i = dr.arange(mi.UInt32, self.n_evaluations)
        back = i >= dr.opaque(mi.UInt32, n_front)
        if not len(self._back_of):  # no blade points (e.g. sensors): fronts only
            return i, back
        f_back = dr.gather(mi.UInt32, self._back_of_dr, i - dr.opaque(mi.UInt32, n_front), back)
        return dr.select(back, f_back, i), back

    # -- Dr.Jit pieces -------------------------------------------------------------------
    def _arrays(self):
        """Sample positions, normals, frames, first directions and random columns, as Dr.Jit arrays.

        Built once and kept, from the evaluations' points (:meth:`_evaluations`,
        :meth:`_place`) and the per-replicate shifts, without per-evaluation numpy arrays.
        """
        if getattr(self, "_dr", None) is None:
            import drjit as dr

            mi = self.fs.mi
            f, back = self._evaluations()
            si, x_u = self._point_coordinates(f)
            x, n, _ = self._place(si, x_u)
            n = [dr.select(back, -c, c) for c in n]
            valid = (n[0] != 0) | (n[1] != 0) | (n[2] != 0)
            n = [dr.select(valid, c, up) for c, up in zip(n, (0.0, 0.0, 1.0))]
            # A point below the soil surface (CPlantBox starts each stem at the seed, 3 mm deep)
            # receives nothing: the analytic soil stops rays going down only, so without this a
            # buried point's rays going up would see the sun and sky (docs/light.md, "Model").
            valid &= x[2] >= 0.0
            if self.fs.tracer is not None:
                # A point on a face overhanging the periodic cell is the same point of the
                # infinite field as its image inside the cell: rays start from there.
                x = self.fs.tracer.wrap64(x)
            eps = dr.opaque(mi.Float64, self.epsilon_m)
            o = mi.Point3f(*(mi.Float(c + eps * nc) for c, nc in zip(x, n)))
            nrm = mi.Vector3f(*(mi.Float(c) for c in n))
            dr.eval(o, nrm, valid)
            # Random columns generated here from the per-replicate shifts: u = {shift + j·α}.
            row, j_int = self._replicate_index(f)
            base = row * dr.opaque(mi.UInt32, self._shift.shape[-1])
            jj = mi.Float(j_int)
            shift = owned(self._shift.reshape(-1), mi.Float)
            front_dims, back_dims = _side_dims(self.bounces)

            def column(dim):
                delta = dr.gather(mi.Float, shift, base + self._column_of[dim])
                if np.isnan(self._alpha[dim]):
                    # The replicate's keyed shift (24 bits) keys the hash; the point index varies it.
                    h = hash32(hash32(mi.UInt32(delta * 2.0**24) + (dim * 0x9E3779B9) % 2**32) + j_int)
                    return mi.Float(h >> 8) * 2.0**-24
                step = round(float(self._alpha[dim]) * 2**32) % 2**32  # α in 32-bit fixed point
                exact = mi.Float(((mi.UInt32(delta * 2.0**24) << 8) + j_int * step) >> 8) * 2.0**-24
                return dr.select(j_int < _FLOAT32_J, delta + jj * float(self._alpha[dim]), exact)

            u = []
            for df, db in zip(front_dims, back_dims):
                v = dr.select(back, column(db), column(df))
                v = dr.minimum(v - dr.floor(v), 1.0 - 2.0**-24)
                dr.eval(v)
                u.append(v)
            frame = mi.Frame3f(nrm)
            d = frame.to_world(mi.warp.square_to_cosine_hemisphere(mi.Point2f(u[0], u[1])))
            dr.eval(d, frame, valid)
            self._dr = (o, nrm, frame, d, u, valid)
        return self._dr

    def _absorptance(self, frame, w_world):
        """Absorptance 1 − ρ(θ) of the leaf for light arriving from ``w_world`` (tabulated albedo)."""
        return 1.0 - leaf_albedo(self.fs.bsdf, frame.to_local(w_world).z)

    def _sun_vector(self):
        """The sun direction as an *opaque* Dr.Jit vector: the render's kernel then does not
        depend on the sun, so one compiled kernel serves every time step of a day (and is
        cached on disk); with literals every sun position compiled its own."""
        import drjit as dr

        return dr.opaque(self.fs.mi.Vector3f, [float(c) for c in self.fs.sun])

    def _occluded(self, kind: str, o, d, active):
        """Periodic shadow rays towards the sun (``d``), logged for :meth:`render`'s meta."""
        tracer = self.fs.tracer
        blocked, capped, k = tracer.occluded(o, d, active, cap=tracer.crossings_for(self.fs.sun), fuse=self._fuse)
        self._wrap_log.append((kind, active, capped, k))
        return blocked

    def _per_evaluation(self):
        """Evaluation-level sun/sky incident and absorbed values at the current leaf parameters and
        sun (Dr.Jit; attached to the parameters when their gradients are enabled): the kept
        geometry (:meth:`_geometry`), this sun's shadow rays (:meth:`_sun_rays`), weighed
        (:meth:`_weigh`, :meth:`_values`)."""
        geo = self._geometry()
        kept = self._suns_kept.get(self._sun_key())
        sun_rays = kept[0] if kept is not None else self._sun_rays(geo)
        return self._values(geo, self._weigh(geo), sun_rays)

    def _trace(self, o, d, u):
        r"""The geometry of the paths from ``o`` along ``d``: what does not depend on the leaf
        parameters or the sun.

        Directions come from the BSDF's frozen sampling (``LeafBSDF.sample_direction``) and the
        random columns ``u``. A path is followed while its sample is usable (``ok``), whatever
        its weight: where a parameter point's BSDF value is 0 (e.g. a transmission at
        subsurface 0) that point's throughput becomes exactly 0 and every later contribution
        adds +0, so its values are bitwise those of a path stopped there (which
        :meth:`render` did before the geometry was shared across parameter points).

        Returns one dict per order 0 … ``bounces``: ``escaped`` (the ray left to the sky) and
        ``dz`` (its direction's z) for the sky; for orders below ``bounces`` also the vertex:
        ``hit_leaf``, ``hit_soil``, the point ``p``, the leaf's normal ``n``, shading ``frame``,
        incoming direction ``wi`` (local), and the sample leaving it (``wo`` local to the side of
        ``wi``, its ``pdf``, ``ok``).
        """
        import drjit as dr

        mi, fs = self.fs.mi, self.fs
        n_ev = self.n_evaluations
        active = mi.Bool(dr.full(mi.Bool, True, n_ev))
        periodic = fs.tracer is not None
        orders = []
        for depth in range(self.bounces + 1):
            if periodic:
                hit_leaf, si, hit_soil, p_soil, escaped, capped, k = fs.tracer.intersect(o, d, active, fuse=self._fuse)
                self._wrap_log.append(("path", active, capped, k))
            else:
                ray = mi.Ray3f(o, d)
                si = fs.scene.ray_intersect(ray, active)
                hit_leaf = active & si.is_valid()
                t_soil = dr.select(d.z < 0, -o.z / d.z, dr.inf)
                hit_soil = active & (d.z < 0) & (~hit_leaf | (t_soil < si.t))
                hit_leaf &= ~hit_soil
                escaped = active & ~hit_leaf & ~hit_soil
            order = {"escaped": escaped, "dz": d.z}
            orders.append(order)
            if depth == self.bounces:
                break
            if not periodic:
                p_soil = o + d * t_soil
            si.wi = si.to_local(-d)
            ub = u[_USED_PER_SIDE + _DIMS_PER_BOUNCE * depth : _USED_PER_SIDE + _DIMS_PER_BOUNCE * (depth + 1)]
            s, _, wo, pdf, ok, _, _ = fs.bsdf.sample_direction(si.wi, ub[0], mi.Point2f(ub[1], ub[2]), hit_leaf)
            order.update(
                hit_leaf=hit_leaf,
                hit_soil=hit_soil,
                p=dr.select(hit_leaf, si.p, p_soil),
                n=si.n,
                frame=si.sh_frame,
                wi=si.wi,
                wo=wo,
                pdf=pdf,
                ok=ok,
            )
            active = (hit_leaf & ok) | hit_soil
            o, d = fs.scattered_ray(si, hit_leaf, p_soil, s, wo, mi.Point2f(ub[1], ub[2]), self.epsilon_m)
        return orders

    def _geometry(self):
        """:meth:`_trace`, evaluated once and kept while the BSDF's frozen sampling stays (with
        sampling that follows the parameters, while they stay): every leaf-parameter point and
        every sun shares it.

        Memory: ≈ 100 bytes per evaluation and scattering order (points, normals, frames,
        directions, pdf and masks), plus 5 per evaluation for the last order's escape.
        """
        import drjit as dr

        bsdf = self.fs.bsdf
        key = bsdf.sampling
        if key is None:  # directions follow the parameters: the geometry is theirs
            key = tuple(float(getattr(bsdf, k)[0]) for k in (*LEAF_PARAMETERS, "base_color"))
        if self._kept is None or self._kept[0] != key:
            self._kept = None  # free the old geometry before tracing anew
            self._suns_kept.clear()  # its shadow rays
            with dr.suspend_grad():
                o, _, _, d, u, _ = self._arrays()
                log, self._wrap_log = self._wrap_log, []
                geo = self._trace(o, d, u)
                counts = self._wrap_counts()
                dr.eval(geo, counts)
                self._wrap_log = log
            self._kept = (key, geo, counts)
        return self._kept[1]

    def _weigh(self, geo):
        """Path throughputs at the current leaf parameters: ``(betas, L_sky)``, the throughput
        arriving at each vertex of ``geo`` and the sky radiance the paths bring back (per unit
        DHI). Sun-independent."""
        import drjit as dr

        mi, fs = self.fs.mi, self.fs
        rho_soil = fs.optics.soil_albedo
        beta = mi.Float(dr.ones(mi.Float, self.n_evaluations))
        L_sky = mi.Float(dr.zeros(mi.Float, self.n_evaluations))
        betas = []
        for depth, g in enumerate(geo):
            escaped = g["escaped"]
            if self._scattered_only and depth <= 1:
                # A projection has the sky seen directly (depth 0) and through one leaf or the soil.
                escaped = mi.Bool(False)
            L_sky += dr.select(escaped, beta * fs.sky_radiance(g["dz"]), 0.0)
            if depth == self.bounces:
                break
            betas.append(beta)
            hit_leaf = g["hit_leaf"]
            wi = fs.bsdf._flip(g["wi"], dr.sign(mi.Frame3f.cos_theta(g["wi"])))
            w = fs.bsdf.weight(wi, g["wo"], g["pdf"], g["ok"], hit_leaf)
            beta = dr.select(hit_leaf, beta * w, dr.select(g["hit_soil"], beta * rho_soil, 0.0))
        return betas, L_sky

    def _nee_vertices(self, g, depth: int):
        """The leaf and soil lanes of order ``depth`` of the geometry whose sun the paths take by
        next-event estimation: all, except at the first vertex alongside a projection (it has
        the sun through one leaf or the soil)."""
        if depth == 0 and self._scattered_only:
            return self.fs.mi.Bool(False), self.fs.mi.Bool(False)
        return g["hit_leaf"], g["hit_soil"]

    def _sun_rays(self, geo):
        """The current sun's shadow rays: ``(e_dir, visible)``, the direct sun on each evaluation's
        side (cos⁺ × visibility) and, per vertex of ``geo``, whether the sun is visible from it
        (leaf vertices from the side facing the sun, soil vertices from above). Independent of
        the leaf parameters; ``None`` with the sun below the horizon. Memory: 4 + ``bounces``
        bytes per evaluation."""
        import drjit as dr

        mi, fs = self.fs.mi, self.fs
        if fs.sun[2] <= 0:
            return None
        o, nrm, *_ = self._arrays()
        sun = self._sun_vector()
        cos_s = dr.dot(nrm, sun)
        if self._scattered_only:  # a projection has the direct sun
            e_dir = dr.zeros(mi.Float, self.n_evaluations)
        elif fs.tracer is None:
            blocked = fs.scene.ray_test(mi.Ray3f(o, sun), cos_s > 0)
            e_dir = dr.select((cos_s > 0) & ~blocked, cos_s, 0.0)
        else:
            blocked = self._occluded("sun", o, sun, cos_s > 0)
            e_dir = dr.select((cos_s > 0) & ~blocked, cos_s, 0.0)
        eps = self.epsilon_m
        visible = []
        for depth, g in enumerate(geo[: self.bounces]):
            (hit_leaf, hit_soil), p, n = self._nee_vertices(g, depth), g["p"], g["n"]
            side = dr.sign(dr.dot(n, sun))
            # Leaf vertices: a ray wherever a leaf is hit; where the BSDF towards the sun is 0 at
            # some parameters their term is 0 whatever the ray finds. Leaf and soil vertices are
            # disjoint lanes, cast together: full ray packets (two masked casts cost nearly twice one).
            o_v = dr.select(hit_leaf, p + eps * side * n, p + mi.Vector3f(0, 0, eps))
            if fs.tracer is not None:
                visible.append(~self._occluded("nee", o_v, sun, hit_leaf | hit_soil))
            else:
                visible.append(~fs.scene.ray_test(mi.Ray3f(o_v, sun), hit_leaf | hit_soil))
        return e_dir, visible

    def _values(self, geo, weights, sun_rays):
        """Evaluation-level sun/sky incident and absorbed values from the geometry, the throughputs
        (:meth:`_weigh`) and the sun's shadow rays (:meth:`_sun_rays`), at the current leaf
        parameters and sun. The sun scattered towards the origin comes by next-event estimation
        at every leaf vertex (through the BSDF, reflection or transmission) and soil vertex."""
        import drjit as dr

        mi, fs = self.fs.mi, self.fs
        _, _, frame, d, _, valid = self._arrays()
        betas, L_sky = weights
        n_ev = self.n_evaluations
        L_sun = mi.Float(dr.zeros(mi.Float, n_ev))
        if sun_rays is None:
            e_dir, a_s = mi.Float(dr.zeros(mi.Float, n_ev)), mi.Float(1.0)
        else:
            e_dir, visible = sun_rays
            sun = self._sun_vector()
            rho_soil = fs.optics.soil_albedo
            ctx = mi.BSDFContext()
            for depth, (g, beta, vis) in enumerate(zip(geo, betas, visible)):
                hit_leaf, hit_soil = self._nee_vertices(g, depth)
                si = dr.zeros(mi.SurfaceInteraction3f)
                si.sh_frame, si.wi = g["frame"], g["wi"]
                f_sun = fs.bsdf.eval(ctx, si, si.to_local(sun), hit_leaf)[0]
                L_sun += dr.select(hit_leaf & vis, beta * f_sun, 0.0)
                L_sun += dr.select(hit_soil & vis, beta * rho_soil / math.pi * sun.z, 0.0)
            a_s = self._absorptance(frame, sun)
        a_d = self._absorptance(frame, d)
        e_sunscat, e_sky = math.pi * L_sun, math.pi * L_sky
        vals = {
            "incident_sun": e_dir + e_sunscat,
            "incident_sky": e_sky,
            "absorbed_sun": e_dir * a_s + e_sunscat * a_d,
            "absorbed_sky": e_sky * a_d,
        }
        return {k: dr.select(valid, v, 0.0) for k, v in vals.items()}

    # -- public --------------------------------------------------------------------------
    def render(self) -> Irradiance:
        """Primal pass: per-segment sun/sky incident and absorbed irradiance with standard errors.

        In a periodic scene ``meta["periodic"]`` holds the ray counts of :meth:`_wrap_summary`
        (the kept geometry's rays, :meth:`_geometry`, are counted in every render that uses it).
        At a sun rendered before, the shadow rays kept from then are weighed again (no new rays;
        bitwise that render's values and counts), within the memory budget of
        :meth:`_trim_sun_rays`.
        """
        import drjit as dr

        with dr.suspend_grad():
            self._wrap_log, self._fuse = [], True
            try:
                geo = self._geometry()
                kept = self._suns_kept.pop(self._sun_key(), None)
                sun_rays = self._sun_rays(geo) if kept is None else kept[0]
                vals = self._values(geo, self._weigh(geo), sun_rays)
            finally:
                self._fuse = False
            if kept is None:
                counts = self._wrap_counts(self._kept[2])
                # One evaluation of everything: the sun's shadow rays (periodic walks included)
                # and the weights are one kernel; evaluating the ray counts apart would recompute
                # the walks.
                dr.eval(vals, counts, *(() if sun_rays is None else (sun_rays,)))
                kept = (sun_rays, self._wrap_summary(counts))
            else:  # a sun rendered before: its shadow rays only weighed, as render_many does
                dr.eval(vals)
            # The shadow rays are kept for later renders and a vjp at this sun (4 + bounces
            # bytes per evaluation), within the same budget as the projection's sun hits.
            self._suns_kept[self._sun_key()] = kept
            self._trim_sun_rays()
            _trim_suns(self._direct, self.fs)
            return self._irradiance(vals, kept[1], self._direct_values())

    def _trim_sun_rays(self) -> None:
        """Drop the least recently rendered suns' shadow rays, but the current sun's, while the
        kept ones hold more than :data:`~lightfit.light.projection.SUN_HITS_BUDGET_BYTES`."""
        per_sun = self.n_evaluations * (4 + self.bounces)
        projection.trim_least_recent(self._suns_kept, lambda _: per_sun, keep={self._sun_key()})

    def _sun_key(self):
        """What the shadow rays depend on: the kept geometry and the sun."""
        return (self._kept[0], tuple(float(c) for c in self.fs.sun))

    def render_many(self, leaf: ArrayLike, suns_deg: ArrayLike | None = None):
        """:meth:`render` at many leaf-parameter points and suns, tracing the paths once.

        With frozen sampling the geometry of every path and every shadow ray is the same at all
        leaf-parameter points (:meth:`_trace`); only the throughputs change. So the paths are
        traced once (kept, :meth:`_geometry`), each sun's shadow rays cast once, and every point
        only weighs them (:meth:`_weigh`, :meth:`_values`: arithmetic, no rays).

        Args:
            leaf: (N, 3) specular, roughness, subsurface, each in [0, 1].
            suns_deg: (T, 2) sun elevation and azimuth, degrees; ``None``: the scene's sun.

        Yields, per row of ``leaf`` as soon as it is done, the list of T :class:`Irradiance`
        that :meth:`render` returns after ``set_optics`` to that point and ``set_sun`` to each sun
        (bitwise; ``meta["periodic"]`` included). The scene's leaf parameters and sun are as the
        caller left them between and after the yields.

        Memory besides the kept geometry: 4 + ``bounces`` bytes per evaluation and sun (the
        shadow rays, kept for all T suns), and 4 × (1 + ``bounces``) bytes per evaluation for
        the point being weighed — independent of N. With ``direct="projection"`` the projected
        hits of all T suns are kept too while the generator runs; when it ends or is closed they
        are trimmed to the projection's memory budget, as after :meth:`render`
        (:meth:`DirectProjection.trim_suns`).
        """
        import drjit as dr

        leaf = np.atleast_2d(np.asarray(leaf, dtype=np.float64))
        if leaf.ndim != 2 or leaf.shape[1] != len(LEAF_PARAMETERS) or not np.all((leaf >= 0) & (leaf <= 1)):
            raise InputError(
                f"leaf points of shape {leaf.shape}",
                parameter="leaf",
                expected="(N, 3) specular, roughness, subsurface, each in [0, 1]",
            )
        fs = self.fs
        suns = None if suns_deg is None else np.atleast_2d(np.asarray(suns_deg, dtype=np.float64))
        if suns is not None and (suns.ndim != 2 or suns.shape[1] != 2):
            raise InputError(f"suns of shape {suns.shape}", parameter="suns_deg", expected="(T, 2) elevation, azimuth")

        def scene_state():
            return fs.optics, fs.sun.copy()

        def restore(state):
            fs.set_optics(**{k: getattr(state[0], k) for k in LEAF_PARAMETERS})
            fs.optics, fs.sun = state

        state = scene_state()
        sun_vectors = [state[1]] if suns is None else []
        try:
            for el, az in () if suns is None else suns:
                fs.set_sun(el, az)
                sun_vectors.append(fs.sun.copy())
            if self._direct is not None:
                self._direct.trim_suns(keep=sun_vectors)
            # The shadow rays of every sun, once; their ray counts with the geometry's.
            with dr.suspend_grad():
                self._wrap_log, self._fuse = [], True
                try:
                    geo = self._geometry()
                    rays = []
                    for s in sun_vectors:
                        fs.sun = s
                        r = self._sun_rays(geo)
                        counts = self._wrap_counts(self._kept[2])
                        dr.eval(r, counts)
                        rays.append((s, r, self._wrap_summary(counts)))
                finally:
                    self._fuse = False
        finally:
            restore(state)
        try:
            for x in leaf:
                state = scene_state()
                try:
                    # The parameters stay literals, as in render(): made opaque, every point would
                    # share compiled kernels (≈ 0.1 s less per point on the quick field) but the
                    # values moved by float32 round-off (≈ 6e-8), no longer bitwise those of render().
                    fs.set_optics(**dict(zip(LEAF_PARAMETERS, x)))
                    out = []
                    with dr.suspend_grad():
                        weights = self._weigh(geo)
                        dr.eval(weights)
                        for s, r, periodic in rays:
                            fs.sun = s
                            vals = self._values(geo, weights, r)
                            dr.eval(vals)
                            out.append(self._irradiance(vals, periodic, self._direct_values()))
                finally:
                    restore(state)
                yield out
        finally:
            _trim_suns(self._direct, fs)

    def _direct_values(self) -> dict | None:
        """:func:`_projected` of this estimator's projection (``None`` unless ``direct="projection"``)."""
        return _projected(self._direct)

    def _irradiance(self, vals: dict, periodic: dict | None, direct: dict | None = None) -> Irradiance:
        """Per-segment means, standard errors and replicate means of evaluated per-evaluation values,
        plus ``direct`` (:meth:`_direct_values`) replicate by replicate."""
        ev = {k: np.array(v, dtype=np.float64) for k, v in vals.items()}  # copies: modified below
        S, K = len(self.segment_id), self.samples
        n_front = S * K
        out, se, front, reps = {}, {}, {}, {}
        for k, v in ev.items():
            if not np.isfinite(v).all():
                raise FloatingPointError(f"non-finite {k} in {int((~np.isfinite(v)).sum())} evaluation(s)")
            # Evaluations are every point's front side in (segment, point) order, then the back
            # sides of blade points (each point once): the sum per point without np.add.at
            # (18 → 7 ms per part for the main job), in the same order, so with the same rounding;
            # in place (``v`` is this function's own copy), after the fronts' mean is taken.
            per_point = v[:n_front].reshape(S, K)
            front[k] = per_point.mean(1)
            per_point.reshape(-1)[self._back_of] += v[n_front:]
            out[k] = per_point.mean(1)
            rep = per_point.reshape(S, self.replicates, self.per_replicate).mean(2)
            if direct is not None:  # independent estimates of the same expectation's two terms
                front[k] = front[k] + direct["front"][k].mean(1)
                out[k] = out[k] + direct[k].mean(1)
                rep = rep + direct[k]
            se[k] = rep.std(1, ddof=1) / math.sqrt(self.replicates)
            reps[k] = rep
        return Irradiance(
            self.segment_id,
            out["incident_sun"],
            out["incident_sky"],
            out["absorbed_sun"],
            out["absorbed_sky"],
            se,
            K,
            self.bounces,
            self.seed,
            self.fs.sun.copy(),
            cov=_sun_sky_cov(reps),
            meta={
                "n_evaluations": self.n_evaluations,
                "optics": self.fs.optics,
                "front": front,
                "is_blade": self.is_blade,
                "area_m2": self.area_m2,
                "replicate_means": reps,
                "direct": self.direct,
                **({} if periodic is None else {"periodic": periodic}),
                **({} if self._direct is None else {"direct_projection": self._direct.summary()}),
            },
        )

    def _wrap_counts(self, base: dict | None = None) -> dict | None:
        """Per evaluation and kind of ray: rays cast, rays capped and crossings made (lazy UInt32
        arrays of :attr:`_wrap_log`, to be evaluated with the render), added to ``base`` (counts
        of the same form, e.g. of kept paths)."""
        if self.fs.tracer is None:
            return None
        import drjit as dr

        U = self.fs.mi.UInt32
        zero = dr.zeros(U, self.n_evaluations)
        counts = {}
        for kind in ("path", "sun", "nee"):
            b = {} if base is None else base[kind]
            rays, capped, crossings = (b.get(c, zero) for c in ("rays", "capped", "crossings"))
            for _, a, c, k in (x for x in self._wrap_log if x[0] == kind):
                rays = rays + dr.select(a, U(1), U(0))
                capped = capped + dr.select(c, U(1), U(0))
                crossings = crossings + dr.select(a, k, U(0))
            counts[kind] = {"rays": rays, "capped": capped, "crossings": crossings}
        self._wrap_log = []
        return counts

    def _wrap_summary(self, counts: dict | None) -> dict | None:
        """Rays cast, crossings made and rays stopped by the crossing cap, per kind of ray.

        Kinds: ``"path"`` (the first cosine-sampled ray and every scattered segment),
        ``"sun"`` (direct-sun shadow rays), ``"nee"`` (sun shadow rays from leaf and soil
        vertices). ``capped_share`` is capped ÷ rays over all kinds. ``counts``: the evaluated
        :meth:`_wrap_counts`.
        """
        tracer = self.fs.tracer
        if tracer is None:
            return None
        out = {
            "cell_m": tuple(float(v) for v in tracer.cell.size_m),
            "z_top_m": tracer.z_top,
            "crossing_cap": tracer.cap,
            "sun_crossing_cap": tracer.crossings_for(self.fs.sun),
            "crossing_tolerance": tracer.tolerance,
        }
        for kind, c in counts.items():
            out[kind] = {k: int(np.asarray(v, dtype=np.int64).sum()) for k, v in c.items()}
        rays = sum(out[k]["rays"] for k in counts)
        out["capped_share"] = sum(out[k]["capped"] for k in counts) / max(rays, 1)
        return out

    def vjp(self, cotangent: dict[str, np.ndarray]) -> dict[str, float]:
        """Gradient of Σ_parts Σ_segments cotangent[part]·value[part] w.r.t. the leaf parameters.

        ``cotangent`` maps part names (:data:`PARTS`) to per-segment arrays (missing parts are
        zero). Uses the same random numbers as :meth:`render`.
        """
        import drjit as dr

        mi = self.fs.mi
        S, K = len(self.segment_id), self.samples
        c = _checked_cotangent(cotangent, S)
        si = self._evaluations()[0] // dr.opaque(mi.UInt32, K)
        w = {p: dr.gather(mi.Float, owned(c[p] / K, mi.Float), si) for p in PARTS}
        # Differentiate with respect to per-lane copies of the parameters: the backward pass is
        # then elementwise (a handful of fused kernels) instead of one reduction kernel per use
        # of a scalar parameter; the lanes are summed at the end.
        bsdf = self.fs.bsdf
        saved = {k: getattr(bsdf, k) for k in LEAF_PARAMETERS}
        wide = {k: dr.opaque(mi.Float, float(saved[k][0]), self.n_evaluations) for k in LEAF_PARAMETERS}
        try:
            for k, v in wide.items():
                dr.enable_grad(v)
                setattr(bsdf, k, v)
            self._wrap_log = []
            vals = self._per_evaluation()
            self._wrap_log = []
            # With a projection and one bounce the paths carry nothing: no dependence to follow.
            dr.backward(dr.sum(sum(w[p] * vals[p] for p in PARTS)), flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
            grads = {k: sum_float64(dr.grad(v)) for k, v in wide.items()}
        finally:
            for k, v in saved.items():
                setattr(bsdf, k, v)
        g = _projection_vjp(self._direct, c)
        return {k: grads[k] + g[k] for k in grads}


def _checked_cotangent(cotangent: dict, S: int) -> dict[str, np.ndarray]:
    """A vjp's ``cotangent`` as one (S,) float64 array per part (:data:`PARTS`; missing parts 0), or
    :class:`InputError` naming the output of an unknown name or a shape other than (), (1,), (S,)."""
    unknown = set(cotangent) - set(PARTS)
    if unknown:
        raise InputError(f"unknown output(s) {sorted(unknown)}", parameter="cotangent", expected=", ".join(PARTS))
    c = {}
    for p in PARTS:
        v = np.asarray(cotangent.get(p, 0.0), dtype=np.float64)
        if v.shape not in ((), (1,), (S,)):  # numpy's broadcast error named no output
            raise InputError(
                f"cotangent[{p!r}] of shape {v.shape}", parameter="cotangent", expected=f"a scalar or shape ({S},)"
            )
        c[p] = np.broadcast_to(v, (S,))
    return c


def _trim_suns(proj: DirectProjection | None, fs: FieldScene) -> None:
    """Hold a projection's kept sun hits within its memory budget, the scene's sun's kept
    (:meth:`DirectProjection.trim_suns`): after a render, a reverse pass, and a ``render_many``,
    which keeps the hits of all its suns while it weighs them at every leaf point. Each sun's hits
    take ≈ 9–45 bytes per ray that meets a segment."""
    if proj is not None:
        proj.trim_suns(keep=[fs.sun])


def _projected(proj: DirectProjection | None) -> dict | None:
    """A projection's replicate values (S, R) per part (:data:`PARTS`) and their front-side
    shares (key ``front``), at the current leaf parameters and sun; ``None`` for no projection."""
    if proj is None:
        return None
    out, front = {}, {}
    for kind in ("sun", "sky"):
        v = proj.values(kind)
        if v is None:  # the sun below the horizon
            v = dict.fromkeys(("incident", "absorbed", "incident_front", "absorbed_front"), 0.0)
        for part in ("incident", "absorbed"):
            out[f"{part}_{kind}"] = np.broadcast_to(v[part], (proj.S, proj.R))
            front[f"{part}_{kind}"] = np.broadcast_to(v[f"{part}_front"], (proj.S, proj.R))
    return {**out, "front": front}


def _with_projected(reps: dict, front: dict, d: dict | None, idx=slice(None)) -> tuple[dict, dict]:
    """Replicate means and front-side means of the paths plus a projection's (:func:`_projected`,
    rows ``idx``): independent estimates of the two terms of one expectation, added replicate by
    replicate."""
    if d is None:
        return reps, front
    return (
        {p: reps[p] + d[p][idx] for p in PARTS},
        {p: front[p] + d["front"][p][idx].mean(1) for p in PARTS},
    )


def _projection_vjp(proj: DirectProjection | None, c: dict) -> dict[str, float]:
    """A projection's gradient of Σ c[part]·value over :data:`PARTS` (zeros without a projection)."""
    grads = dict.fromkeys(LEAF_PARAMETERS, 0.0)
    for kind in ("sun", "sky") if proj is not None else ():
        g = proj.vjp(kind, c[f"incident_{kind}"], c[f"absorbed_{kind}"])
        grads = {k: grads[k] + g[k] for k in grads}
    if proj is not None:  # the sun's hits, if cast here, within the budget as after a render
        _trim_suns(proj, proj.fs)
    return grads


def _sun_sky_cov(reps: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Covariance of the sun and sky parts' estimates from R replicate means ((S, R) per part):
    the replicates' sample covariance ÷ R, as ``se²`` is their sample variance ÷ R."""
    out = {}
    for part in ("incident", "absorbed"):
        a, b = reps[f"{part}_sun"], reps[f"{part}_sky"]
        R = a.shape[1]
        out[part] = ((a - a.mean(1, keepdims=True)) * (b - b.mean(1, keepdims=True))).sum(1) / ((R - 1) * R)
    return out


def _from_replicate_means(
    segment_id: np.ndarray, reps: dict, front: dict, samples: np.ndarray, bounces: int, seed: int, sun, meta: dict
) -> Irradiance:
    """An :class:`Irradiance` from per-part replicate means (S, R) and front-side means (S,)."""
    R = next(iter(reps.values())).shape[1]
    out = {k: v.mean(1) for k, v in reps.items()}
    se = {k: v.std(1, ddof=1) / math.sqrt(R) for k, v in reps.items()}
    r = Irradiance(
        segment_id,
        out["incident_sun"],
        out["incident_sky"],
        out["absorbed_sun"],
        out["absorbed_sky"],
        se,
        int(samples.max()),
        bounces,
        seed,
        np.array(sun, dtype=np.float64),
        cov=_sun_sky_cov(reps),
        meta={**meta, "front": front, "replicate_means": reps, "samples_per_segment": samples},
    )
    return r


def render_adaptive(
    field_scene: FieldScene,
    segment_ids: ArrayLike,
    target_rse: float,
    *,
    bounces: int = DEFAULT_BOUNCES,
    seed: int = 0,
    pilot: int = MIN_PILOT,
    growth: int = 2,
    max_samples: int = MAX_ADAPTIVE_SAMPLES,
    dni: float = 1.0,
    dhi: float = CLEAR_DAY_DHI_PER_DNI,
    direct: str = "paths",
    direct_rays_per_m2: float | tuple[float, float] = DEFAULT_RAYS_PER_M2,
    dark_floor: float = DARK_FLOOR,
) -> Irradiance:
    r"""Per-segment irradiance with samples added, in rounds, where the error is above ``target_rse``.

    Round 0 renders every segment with ``pilot`` points; each further round multiplies the points
    per replicate by ``growth`` for the segments whose relative SE of absorbed PAR
    (``dni·sun + dhi·sky``, :meth:`Irradiance.relative_se`, with the sun–sky covariance) is
    still above ``target_rse``, by continuing the same randomised Kronecker sequences
    (:class:`SegmentEstimator` with ``first``): a segment that stops with K points has exactly
    the estimate of ``SegmentEstimator(samples=K)`` (up to summation order). Segments stop at
    ``max_samples`` (or, where a last round to it would add fewer than 32 points, at the round
    before: fewer would be too few for the 8 replicates). A segment receiving nothing so far
    (zero estimate, no SE to judge) goes on until its points K reach :math:`3/f` (``dark_floor``
    f; the cap when f = 0): by the rule of three its light is then below the floor with 95 %
    confidence. (Stopping such segments after the pilot, as before, left those with rare light
    at zero: the segments below the floor came out 23–27 % low, ``experiments/dark_floor_bias.py``.)
    Deterministic given seed and target (the stopping rule reads only the estimates).

    **The light floor.** A segment is done when its SE :math:`\sigma_s` of absorbed PAR meets

    .. math:: \sigma_s \le t\,\max\bigl(v_s,\ f\,(\mathrm{dni}\,\cos\theta_\odot + \mathrm{dhi})\bigr),

    :math:`v_s` its estimate, :math:`t` = ``target_rse``, :math:`f` = ``dark_floor``
    (:data:`DARK_FLOOR`) and :math:`\mathrm{dni}\cos\theta_\odot + \mathrm{dhi}` the light on a
    horizontal surface above the canopy (sun zenith :math:`\theta_\odot`). Above the floor that is
    the relative target; below, an absolute one: points are not spent on a relative error of almost
    nothing. The absolute goal is taken from :math:`3/f` points on: a dark segment's few hits give
    too unreliable an SE before (stopping on it selected low estimates). The floor depends on the
    scene's sun and the weights only, not on which segments are rendered, so tiles of a field
    still allocate as the whole field would. ``dark_floor=0``: the relative target everywhere.

    ``meta``: ``samples_per_segment`` (K per segment), ``reached_rse`` (relative SE of absorbed
    PAR at ``dni``/``dhi``), ``stopped_on_floor`` (segments done by the floor: a relative SE above
    the target and an absolute one within it, or no light in :math:`3/f` points),
    ``floor_absorbed`` (the floor, the threshold on absorbed PAR at ``dni``/``dhi``),
    ``dark_floor``, ``rounds`` (K and segments rendered per round), ``n_evaluations`` (all
    rounds), ``target_rse``. ``samples`` is the largest K.

    Stopping when the *estimated* SE falls below the target slightly favours replicates that
    happen to agree (a selection effect, as in any sequential design); with 8 replicates the
    reached error is within about 1.2 × the target for segments that stopped.

    ``direct="projection"`` (:class:`SegmentEstimator`): the direct light is projected once for
    all segments and the rounds add paths with scattered light only. A segment still above the
    target whose projected part alone is above it (more points cannot reduce that: typically
    stems deep in the canopy, which few projected rays reach; or no projected ray met it at all)
    takes its direct light from its own points from then on: the points it has are rendered
    again with ``direct="paths"`` (their scattered-only values dropped), as are its later rounds,
    so it ends with exactly the estimate of a ``direct="paths"`` render with its K.
    ``meta["projected"]``: whose direct light is projected. The switch is decided on the
    projection's realised values, which it discards, so the values kept lean high: +0.04 % on
    the canopy at the default rays per m², up to +1 % at 1/25 of them (a 10 % target;
    ``experiments/adaptive_switch_bias.py``, docs/light.md).
    """
    check_target_rse(target_rse)
    check_dark_floor(dark_floor)
    check_par_weights(dni, dhi)
    if not isinstance(pilot, (int, np.integer)) or pilot < MIN_PILOT:
        raise InputError(f"pilot={pilot!r}", parameter="pilot", expected=f"an integer ≥ {MIN_PILOT} (8 replicates)")
    if not isinstance(growth, (int, np.integer)) or growth < 2:
        raise InputError(f"growth={growth!r}", parameter="growth", expected="an integer ≥ 2")
    if not isinstance(max_samples, (int, np.integer)) or max_samples < pilot:
        raise InputError(
            f"max_samples={max_samples!r}", parameter="max_samples", expected=f"an integer ≥ pilot ({pilot})"
        )
    check_direct_light(field_scene, direct, direct_rays_per_m2, replicates_for(int(pilot)))
    check_bounces(bounces)
    check_seed(seed)
    ids = checked_segment_ids(segment_ids)
    S, R = len(ids), replicates_for(int(pilot))
    J, J_max = -(-int(pilot) // R), max(-(-int(pilot) // R), int(max_samples) // R)
    projected = np.full(S, direct == "projection")  # per segment: its direct light projected
    proj, D = None, None
    sums = {p: np.zeros((S, R)) for p in PARTS}
    fsum = {p: np.zeros(S) for p in PARTS}
    M = np.zeros(S, dtype=np.int64)
    active = np.ones(S, bool)
    rse = np.full(S, np.inf)
    goal = np.full(S, float(target_rse))  # each segment's relative target, the floor's included
    floor = float(dark_floor) * (dni * max(float(field_scene.sun[2]), 0.0) + dhi)
    if dark_floor > 0 and floor == 0:  # a sun below the horizon and no sky: every segment went to the cap
        raise InputError(
            f"dni={dni:g} with the sun {math.degrees(math.asin(float(field_scene.sun[2]))):.1f}° high and dhi=0",
            parameter="dni, dhi",
            expected="light above the canopy to judge the error by (a sun above the horizon or dhi > 0)",
        )
    # Points after which a segment that has received nothing is below the floor (rule of three).
    zero_points = math.ceil(3.0 / dark_floor) if floor > 0 else math.inf
    first, rounds, n_eval, meta0 = 0, [], 0, None

    def add(rows, n_points, first_point, mode):
        """Render ``n_points`` more points per replicate of segments ``rows`` and add them."""
        r = SegmentEstimator(
            field_scene,
            ids[rows],
            samples=R * n_points,
            bounces=bounces,
            seed=seed,
            first=first_point,
            direct=mode,
        ).render()
        for p in PARTS:
            sums[p][rows] += r.meta["replicate_means"][p] * n_points
            fsum[p][rows] += r.front(p) * (R * n_points)
        return r

    def relative_goal(value):
        """Each segment's relative target: ``target_rse`` × max(1, floor / value) (inf at 0)."""
        ratio = np.divide(floor, value, out=np.full(len(value), np.inf), where=value > 0)
        return target_rse * np.maximum(1.0, ratio)

    def estimate(rows):
        return _from_replicate_means(
            ids[rows],
            *_with_projected(
                {p: sums[p][rows] / M[rows, None] for p in PARTS},
                {p: fsum[p][rows] / (R * M[rows]) for p in PARTS},
                D,
                rows,
            ),
            R * M[rows],
            bounces,
            seed,
            field_scene.sun,
            {},
        )

    while True:
        idx = np.flatnonzero(active)
        evaluations = 0
        for rows, mode in ((idx[projected[idx]], "none"), (idx[~projected[idx]], "paths")):
            if len(rows):
                r = add(rows, J - first, first, mode)
                evaluations += r.meta["n_evaluations"]
                if meta0 is None:  # round 0: every segment, in one mode
                    meta0 = {k: r.meta[k] for k in ("optics", "is_blade", "area_m2")}
        if proj is None and direct == "projection":
            proj = DirectProjection(
                field_scene,
                ids,
                meta0["area_m2"],
                replicates=R,
                seed=seed,
                rays_per_m2=direct_rays_per_m2,
                bounces=bounces,
            )
            d = _projected(proj)  # writable copies: switched segments' rows are zeroed
            D = {p: np.array(d[p]) for p in PARTS} | {"front": {p: np.array(d["front"][p]) for p in PARTS}}
        M[idx] = J
        sub = estimate(idx)
        rse[idx] = sub.relative_se("absorbed", dni, dhi)
        value = sub.total("absorbed", dni, dhi)
        goal[idx] = relative_goal(value)
        if D is not None:
            # A projected part alone above the target cannot be reduced by more points: such a
            # segment takes its direct light from its own points instead (its points rendered
            # again, then paths rounds), exactly as a direct="paths" render.
            own = D["absorbed_sun"][idx] * dni + D["absorbed_sky"][idx] * dhi
            own_rse = np.divide(own.std(1, ddof=1) / math.sqrt(R), value, out=np.zeros(len(idx)), where=value > 0)
            # No projected ray met it (too few rays per m² for its size): its direct light is
            # unknown, not 0 with SE 0, and more points cannot add it.
            own_rse[~(own != 0).any(1)] = np.inf
            # Judged against the relative target, so that every segment the floor does not stop
            # switches exactly as it would without the floor.
            switch = idx[projected[idx] & (rse[idx] > target_rse) & (own_rse > target_rse)]
            if len(switch):
                for p in PARTS:  # its points again, with their own direct light
                    sums[p][switch] = 0.0
                    fsum[p][switch] = 0.0
                evaluations += add(switch, J, 0, "paths").meta["n_evaluations"]
                projected[switch] = False
                for p in PARTS:
                    D[p][switch] = 0.0
                    D["front"][p][switch] = 0.0
                again = estimate(switch)
                rse[switch] = again.relative_se("absorbed", dni, dhi)
                goal[switch] = relative_goal(again.total("absorbed", dni, dhi))
        n_eval += evaluations
        rounds.append({"samples": R * J, "segments": int(len(idx)), "evaluations": int(evaluations)})
        # A segment without light so far, or within the floor's goal but not the relative target,
        # goes on until zero_points: its few hits make its SE too unreliable to stop on earlier.
        relative_met = rse[idx] <= target_rse
        active[idx] = (R * J < zero_points) & ~relative_met | (rse[idx] > goal[idx]) & np.isfinite(rse[idx])
        nxt = min(J * int(growth), J_max)
        # A round's R·(nxt − J) points per segment must keep the R replicates (replicates_for: 32
        # points or more); a last step to the cap shorter than that is not taken.
        if J >= J_max or not active.any() or replicates_for(R * (nxt - J)) != R:
            break
        first, J = J, nxt
    return _from_replicate_means(
        ids,
        *_with_projected({p: sums[p] / M[:, None] for p in PARTS}, {p: fsum[p] / (R * M) for p in PARTS}, D),
        R * M,
        bounces,
        seed,
        field_scene.sun,
        {
            **meta0,
            "n_evaluations": n_eval,
            "reached_rse": rse,
            "stopped_on_floor": (R * M >= zero_points) & ~(rse <= target_rse) & ~(rse > goal),
            "floor_absorbed": floor,
            "dark_floor": float(dark_floor),
            "rounds": rounds,
            "target_rse": float(target_rse),
            "direct": direct,
            **({} if proj is None else {"direct_projection": proj.summary(), "projected": projected}),
        },
    )


class AdaptiveEstimator:
    """:class:`SegmentEstimator`'s ``render``/``vjp`` with K per segment chosen for a target error.

    At construction :func:`render_adaptive` picks each segment's K at the scene's current sun
    and leaf parameters; the estimator then keeps that allocation (one
    :class:`SegmentEstimator` per distinct K), so later renders — other suns, other leaf
    parameters — use fixed sample sets: common random numbers, and gradients equal to
    finite differences, as with a fixed K. ``allocation`` is the adaptive render itself
    (``meta["reached_rse"]`` etc.).
    """

    def __init__(self, field_scene: FieldScene, segment_ids: ArrayLike, target_rse: float, **kwargs):
        self.fs = field_scene
        self.allocation = render_adaptive(field_scene, segment_ids, target_rse, **kwargs)
        self.segment_id = self.allocation.segment_id
        self.samples = self.allocation.meta["samples_per_segment"]
        self.bounces, self.seed = self.allocation.bounces, self.allocation.seed
        self.is_blade = self.allocation.meta["is_blade"]
        self.area_m2 = self.allocation.meta["area_m2"]
        self.direct = kwargs.get("direct", "paths")
        R = self.allocation.meta["replicate_means"]["incident_sun"].shape[1]
        self._direct = (
            DirectProjection(
                field_scene,
                self.segment_id,
                self.area_m2,
                replicates=R,
                seed=self.seed,
                rays_per_m2=kwargs.get("direct_rays_per_m2", DEFAULT_RAYS_PER_M2),
                bounces=self.bounces,
            )
            if self.direct == "projection"
            else None
        )
        #: Per segment: whether its direct light is projected (:func:`render_adaptive`).
        self.projected = np.asarray(self.allocation.meta.get("projected", np.zeros(len(self.samples), bool)))
        self.groups = [
            (
                np.flatnonzero(sel),
                SegmentEstimator(
                    field_scene,
                    self.segment_id[sel],
                    samples=int(k),
                    bounces=self.bounces,
                    seed=self.seed,
                    direct="none" if projected else "paths",
                ),
            )
            for k in np.unique(self.samples)
            for projected in (True, False)
            if (sel := (self.samples == k) & (self.projected == projected)).any()
        ]
        self.n_evaluations = sum(e.n_evaluations for _, e in self.groups)

    def render(self) -> Irradiance:
        """All segments at their allocated K (:meth:`SegmentEstimator.render` per group)."""
        results = [est.render() for _, est in self.groups]
        _trim_suns(self._direct, self.fs)
        return self._join(results, self._projected_values())

    def render_many(self, leaf: ArrayLike, suns_deg: ArrayLike | None = None):
        """:meth:`SegmentEstimator.render_many` per group, joined: per leaf point the list of
        :meth:`render` results at each sun."""
        leaf = np.atleast_2d(np.asarray(leaf, dtype=np.float64))
        fs = self.fs
        try:
            for x, per_group in zip(leaf, zip(*(est.render_many(leaf, suns_deg) for _, est in self.groups))):
                d = [None] * len(per_group[0])
                if self._direct is not None:  # the projection at this point and each sun
                    optics, sun = fs.optics, fs.sun.copy()
                    try:
                        fs.set_optics(**dict(zip(LEAF_PARAMETERS, x)))
                        for t, row in enumerate([None] if suns_deg is None else np.atleast_2d(suns_deg)):
                            if row is not None:
                                fs.set_sun(*row)
                            d[t] = self._projected_values()
                    finally:
                        fs.set_optics(**{k: getattr(optics, k) for k in LEAF_PARAMETERS})
                        fs.optics, fs.sun = optics, sun
                yield [self._join(rs, dt) for rs, dt in zip(zip(*per_group), d)]
        finally:
            _trim_suns(self._direct, fs)

    def _projected_values(self) -> dict | None:
        """:func:`_projected` at the current sun and leaf, zero for segments whose direct light
        comes from their own paths."""
        d = _projected(self._direct)
        if d is None:
            return None
        keep = self.projected[:, None]
        return {
            **{p: np.where(keep, d[p], 0.0) for p in PARTS},
            "front": {p: np.where(keep, d["front"][p], 0.0) for p in PARTS},
        }

    def _join(self, results: list[Irradiance], d: dict | None = None) -> Irradiance:
        """One :class:`Irradiance` from the groups' renders (same sun, same leaf parameters) and the
        projection's values ``d`` (:func:`_projected`) there."""
        S = len(self.segment_id)
        reps = {p: None for p in PARTS}
        front = {p: np.zeros(S) for p in PARTS}
        for (i, _), r in zip(self.groups, results):
            for p in PARTS:
                m = r.meta["replicate_means"][p]
                if reps[p] is None:
                    reps[p] = np.zeros((S, m.shape[1]))
                reps[p][i] = m
                front[p][i] = r.front(p)
        meta = {k: self.allocation.meta[k] for k in ("optics", "is_blade", "area_m2", "target_rse", "direct")}
        meta["n_evaluations"] = self.n_evaluations
        reps, front = _with_projected(reps, front, d)
        return _from_replicate_means(
            self.segment_id, reps, front, self.samples, self.bounces, self.seed, results[0].sun_vector, meta
        )

    def vjp(self, cotangent: dict[str, np.ndarray]) -> dict[str, float]:
        """:meth:`SegmentEstimator.vjp`, summed over the groups."""
        # Checked as SegmentEstimator.vjp checks it: a wrong shape stopped on numpy's broadcast error.
        c = _checked_cotangent(cotangent, len(self.segment_id))
        out = dict.fromkeys(LEAF_PARAMETERS, 0.0)
        for i, est in self.groups:
            for k, g in est.vjp({p: v[i] for p, v in c.items()}).items():
                out[k] += g
        g = _projection_vjp(self._direct, {p: np.where(self.projected, v, 0.0) for p, v in c.items()})
        return {k: out[k] + g[k] for k in out}
