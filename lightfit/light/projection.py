r"""Direct sun and directly visible sky on every segment, by parallel rays cast *down* into a periodic cell.

The unscattered part of a segment's light is a projection: the sun's beam, and each direction of
the sky, lights what it meets first. So instead of asking, from K points on each segment, whether
the sun and the sky are visible (:mod:`lightfit.light.estimator`, ``direct="paths"``), rays are
launched from the canopy top over the whole cell and each deposits its flux on the first face it
meets (forward, or "light", tracing; the projection Caribu and HELIOS use for direct light).

**Estimator.** Replicate r casts m rays from a jittered n_a × n_b grid over the cell (area
:math:`A_c`) at the canopy top, along :math:`-\omega`: the sun's direction, or for the sky a
cosine-weighted direction (a Kronecker R₂ sequence over the grid cells in tiled Z-order,
shifted per replicate: :data:`SKY_TILE`).
Each carries the flux

.. math::

    \Phi = \frac{A_c}{m}\, w, \qquad w = \omega_z \ \text{(sun, per unit DNI)}, \qquad
    w = \pi L(\omega) \ \text{(sky, per unit DHI; 1 for the isotropic sky)},

and the replicate's value of segment s is :math:`\sum_{\text{rays hitting } s} \Phi / A_s`
(incident) and :math:`\sum \Phi\,(1 - \rho(\mu))/A_s` (absorbed; ρ the leaf's directional albedo,
μ the cosine of incidence). Its expectation is
:math:`\frac{1}{A_s}\int L(\omega) \int_s V(x, \omega)\cos^+\theta\,dA\,d\omega`, exactly the
direct part of the path estimator (its points' sun shadow ray and first ray escaping to the sky;
tested: ``tests/test_light_projection.py``). Blades count both sides (as the path estimator sums
a point's two sides), stems their outer side; rays stopped by the crossing cap carry no light
(counted in :attr:`DirectProjection.capped`). The standard error comes from the R replicates'
spread, as for the paths.

**Light scattered once** (with ``bounces`` ≥ 1) is carried forward too. A ray that meets a leaf
is continued in a direction drawn from the leaf's frozen sampling (``LeafBSDF.sample_direction``,
as the paths draw theirs) and deposits :math:`\Phi\,f\,|\cos\theta_o|/p` on the next face it
meets (light tracing; the BSDF is reciprocal). A ray that reaches the soil is continued in a
cosine-weighted direction and deposits :math:`\Phi\,\rho_{soil}` (a Lambertian soil: f cos/p = ρ).
Only a share of the rays is continued (Russian roulette, :data:`CONTINUED_SHARE`, each
carrying the inverse share of the flux): they cost more than they bring.
The paths then leave out the sun and the sky through one leaf or the soil (their next-event ray
at the first vertex and the sky found right after it). Through a leaf that carried 0.91 of the
paths' variance (median over the 100-plant cell's segments, one-off split); through the soil,
most of what was left (light scattered twice and more, which stays with the paths, is smooth:
with a black soil the paths' share of a segment's variance has median ≈ 0).

**Why.** Every ray lands on something — a path estimator's rays from a shaded segment mostly meet
leaves — and the rays are stratified over the cell. On the 100-plant cell (PROSPECT leaf, sun at
50°) the projection needs ≈ 11× fewer rays than the paths' shadow rays for the same median
per-segment error of the direct sun, and ≈ 9× fewer first rays for the directly visible sky
(docs/light-sampling.md, "Direct light by projection"). Its cost does not depend on how many segments are
requested: the whole cell is lit.

**Determinism.** Positions and directions are keyed by (seed, kind, ray index) (TEA hashing), and
the per-segment sums are taken in 64-bit fixed point (2⁻³² of a ray's weight), so the order in
which threads add does not change a bit: same seed, same values.

Gradients: ρ(μ) is the only dependence on the leaf parameters (:func:`~lightfit.light.bsdf.leaf_albedo`:
specular and roughness; subsurface does not change a leaf's albedo), differentiated in reverse
mode (:meth:`DirectProjection.vjp`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lightfit.defaults import DEFAULT_RAYS_PER_M2
from lightfit.errors import InputError
from lightfit.light.backend import owned, sum_float64
from lightfit.light.bsdf import LEAF_PARAMETERS, leaf_albedo
from lightfit.light.keyed_random import random_bits
from lightfit.light.periodic import CAPPED, LEAF, SOIL

#: Version of the projection's rays and what they carry: bumped whenever a change moves its values
#: (not only their rounding), so that renders kept on disk (:func:`lightfit.model.emulator.render_key`)
#: are not reused across it. 1: direct light and light scattered once by a leaf; 2: also by the
#: soil, and Russian roulette on the continued rays (:data:`CONTINUED_SHARE`); 3: the sky's directions
#: over the grid cells in tiled Z-order (:data:`SKY_TILE`); 4: random bits from
#: :data:`~lightfit.light.keyed_random.TEA_ROUNDS` rounds of TEA instead of 4 (independent replicates).
PROJECTION_VERSION = 4
#: Most rays per m² a render accepts: 4 × 10⁸ / 5 × 10⁸ already give a 0.85 % median per-segment
#: error on 500 plants (docs/benchmarks.md, GPU), and 10¹⁰ per m² is about an hour of casting per
#: m² of cell on 2 CPU cores; more is taken for a typo (10¹² for 10⁷) rather than run for days.
MAX_RAYS_PER_M2 = 1.0e10


def check_periodic(field_scene) -> None:
    """The projection needs a periodic scene: its rays wrap around the cell."""
    if field_scene.tracer is None:
        raise InputError(
            "direct='projection' on a finite field",
            parameter="direct",
            expected="a periodic scene (FieldScene(..., cell=field.cell)); finite fields use direct='paths'",
        )


def check_rays(rays_per_m2) -> tuple[float, float]:
    """``(sun, sky)`` rays per m² of ground from a pair or one number for both, each in
    (0, :data:`MAX_RAYS_PER_M2`]; InputError otherwise."""
    pair = (rays_per_m2, rays_per_m2) if isinstance(rays_per_m2, (int, float, np.number)) else rays_per_m2
    try:
        out = tuple(float(v) for v in pair)
    except (TypeError, ValueError):
        out = ()
    if (
        len(out) != 2
        or isinstance(rays_per_m2, (bool, str, bytes))  # a string's characters are not a pair
        or not all(math.isfinite(v) and 0 < v <= MAX_RAYS_PER_M2 for v in out)
    ):
        raise InputError(
            f"direct_rays_per_m2={rays_per_m2!r}",
            parameter="direct_rays_per_m2",
            expected=f"rays per m² of ground in (0, {MAX_RAYS_PER_M2:.0e}]: one number, or (sun, sky)",
        )
    return out


#: Most rays of one kind a render casts, all replicates together: a ray's index, which keys its
#: random numbers and its replicate, is a 32-bit integer.
MAX_RAYS_PER_KIND = 2**32


def ray_grids(cell, rays_per_m2, replicates: int) -> dict[str, tuple[int, int]]:
    """Per kind ("sun", "sky"): the grid (n_a, n_b) of one replicate's rays over ``cell`` for
    ``rays_per_m2`` (``(sun, sky)``, :func:`check_rays`) and ``replicates`` R. InputError when a
    kind's R · n_a · n_b rays exceed :data:`MAX_RAYS_PER_KIND` (their indices would wrap), or when
    fewer than one ray per replicate was asked over the cell (it was raised to one silently, shown
    only in the render's meta: 10⁻³ per m² cast 10⁵ times that)."""
    A, B = (float(v) for v in cell.size_m)
    grids = {}
    for kind, rho in zip(("sun", "sky"), rays_per_m2):
        if rho * cell.area_m2 < replicates:
            raise InputError(
                f"direct_rays_per_m2: {rho:.3g} {kind} rays per m² over a cell of {cell.area_m2:.4g} m² are "
                f"fewer than one ray for each of the {replicates} replicates",
                parameter="direct_rays_per_m2",
                expected=f"at least {replicates / cell.area_m2:.3g} per m² on this cell (one ray per replicate; "
                "the default is {:g},{:g})".format(*DEFAULT_RAYS_PER_M2),
            )
        m = max(1, round(rho * cell.area_m2 / replicates))
        nx = max(1, round(math.sqrt(m * A / B)))
        grids[kind] = (nx, max(1, -(-m // nx)))
        n = replicates * nx * grids[kind][1]
        if n > MAX_RAYS_PER_KIND:
            raise InputError(
                f"direct_rays_per_m2: {rho:.3g} {kind} rays per m² over a cell of {cell.area_m2:.4g} m² are "
                f"{n:.3g} rays",
                parameter="direct_rays_per_m2",
                expected=f"at most 2³² = {MAX_RAYS_PER_KIND:.3g} rays of a kind per render (their indices are 32-bit): "
                f"≤ {MAX_RAYS_PER_KIND / cell.area_m2:.3g} per m² on this cell",
            )
    return grids


#: Share of the rays meeting a leaf or the soil whose once-scattered light is carried on, per kind
#: (Russian roulette, each continued ray carrying 1/q of the flux). The continued rays go in every
#: direction, so they trace ≈ 3× slower than the parallel first rays, while they carried ≈ 5 %
#: (sun) and ≈ 1 % (sky) of a segment's variance near the median (500-plant cell, K = 32,
#: 2 × 10⁷ rays per m²): an in-process split of the variance and a cost model put the optimum of
#: variance × time near these values (docs/light-sampling.md, "The soil's light, and fewer continued rays").
CONTINUED_SHARE = {"sun": 0.5, "sky": 0.25}
#: Most rays cast in one pass (one walk, one continuation, one deposit): the rays of a kind are cast
#: in passes of this many (the same rays, keyed by their index, so the same values to the bit), so
#: that a pass's working arrays stay small: on the 500-plant cell at 2 × 10⁷ rays per m², 4.7
#: instead of 9.8 GB peak memory, at the same render time (docs/light-sampling.md, "Where the time goes,
#: and casting in passes").
CAST_CHUNK = 2**22
#: Most bytes of projected sun hits an estimator keeps across suns (2 GiB; the paths' shadow rays
#: have a budget of the same size). They depend on the sun and the seed only, not on the leaf
#: parameters, so a calibration that renders a day's steps at every loss evaluation casts each
#: sun once while they fit (5 steps of the default field, hits and shadow rays kept: a loss 4.6×,
#: a loss and its gradient 4.3× faster; docs/light-sampling.md, "Suns kept within a memory budget"); past
#: the budget the least recently used sun is dropped and cast again when needed.
SUN_HITS_BUDGET_BYTES = 2 * 2**30
_FIXED = 2.0**32  # fixed-point scale of the sums
_NONE = 0xFFFFFFFF  # row of a face whose segment is not requested
_R2 = 1.32471795724474602596  # plastic number: R₂ generators 1/g, 1/g²
#: Cells per side of the tiles in which the sky's rays take consecutive R₂ directions: row-major
#: inside a tile, tiles in Z-order (Morton), so that the rays meeting one segment, from a small
#: patch of cells, get directions spread over the sky whatever the grid. Over the whole grid in
#: row-major order (``0``, before) the spread depended on the row length: at some ray densities the
#: sky part had up to 2.8× the variance (500-plant cell, 10⁸ rays per m²); in Z-order alone, ≈ 8 %
#: more SE where row-major did well (docs/light-sampling.md, "The sky's directions and the grid";
#: ``benchmarks/bench_sky_order.py``). Each ray's direction stays uniform (the per-replicate shift),
#: so any order is unbiased.
SKY_TILE = 16


@dataclass
class Hits:
    """The rays of one kind that met a requested segment (Dr.Jit arrays, one entry per hit).

    ``index``: segment row · R + replicate; ``mu``: |cos| of incidence on the face; ``front``:
    the face's front side was lit; ``weight``: the ray's w (``None``: every ray the same, ``w0``);
    ``rays`` cast (in this pass, :data:`CAST_CHUNK`), ``capped`` of them stopped by the crossing
    cap, ``flux_ref`` = A_c/m; ``part``: ``"direct"``, ``"via_leaf"`` or ``"via_soil"``.
    ``scatter``: for light scattered once by a leaf on its way (``None``: not by a leaf), the
    leaf's sample ``(wi, wo, pdf, ok)`` at the scattering vertex (``LeafBSDF.sample_direction``,
    both directions in the frame flipped to the side of ω_i),
    whose weight f·|cos θ_o|/pdf at the current parameters multiplies the ray's flux.
    ``"via_soil"``: the light was scattered once by the soil on its way (its albedo, at the time
    the values are taken, multiplies the flux: cosine-weighted sampling of a Lambertian soil).
    """

    index: object
    mu: object
    front: object
    weight: object
    w0: float
    rays: int
    capped: int
    flux_ref: float  # m² of ground per ray
    scatter: tuple | None = None
    part: str = "direct"

    @property
    def soil(self) -> bool:
        """The light was scattered once by the soil on its way."""
        return self.part == "via_soil"


def _sun_key(sun) -> tuple:
    return ("sun", *(float(v) for v in sun))


def _hits_bytes(hits: list[Hits]) -> int:
    """Bytes the Dr.Jit arrays of ``hits`` hold: per hit the row index, μ, the side, the sky's
    weight and, for light scattered by a leaf, its sample (two directions, pdf, flag)."""
    import drjit as dr

    def per_hit(h):
        return 4 + 4 + 1 + (0 if h.weight is None else 4) + (0 if h.scatter is None else 12 + 12 + 4 + 1)

    return sum(int(dr.width(h.mu)) * per_hit(h) for h in hits)


def _sky_order(ia, ib, tile: int):
    """Position of grid cell (ia, ib) (Dr.Jit UInt32) in the sky's direction sequence: row-major
    inside ``tile`` × ``tile`` tiles, the tiles in Z-order (their coordinates' bits interleaved).
    Unique while each side has fewer than 2¹² tiles (65 536 cells at ``tile`` = 16): the tile's
    Z-index times ``tile``² then stays below 2³²; beyond, positions wrap mod 2³² (still
    unbiased, see :data:`SKY_TILE`)."""

    def spread(x):  # the 16 low bits of x to the even bits
        x = (x | (x << 8)) & 0x00FF00FF
        x = (x | (x << 4)) & 0x0F0F0F0F
        x = (x | (x << 2)) & 0x33333333
        return (x | (x << 1)) & 0x55555555

    t = tile
    z = spread(ia // t) | (spread(ib // t) << 1)
    return z * (t * t) + (ib % t) * t + ia % t


def trim_least_recent(kept: dict, nbytes, keep=()) -> None:
    """Drop the least recently used entries of ``kept`` (the first in its order: a user moves an
    entry to the end), never those keyed in ``keep``, while all of them together hold more than
    :data:`SUN_HITS_BUDGET_BYTES`; ``nbytes(value)``: the bytes one entry holds. The one budget
    rule for what is kept per sun: the projection's hits and the paths' shadow rays."""
    total = sum(nbytes(v) for v in kept.values())
    for key in [k for k in kept if k not in keep]:
        if total <= SUN_HITS_BUDGET_BYTES:
            break
        total -= nbytes(kept.pop(key))


class DirectProjection:
    """Direct sun and directly visible sky on the requested segments of a periodic scene.

    Args:
        field_scene: the scene; it must be periodic (``FieldScene(..., cell=...)``).
        segment_ids: requested segments, sorted and unique (:class:`SegmentEstimator`'s order).
        area_m2: their one-sided areas, m².
        replicates: R, independent ray sets (the standard error's replicates).
        seed: random seed.
        rays_per_m2: rays per m² of ground, all replicates together: ``(sun, sky)``, or one number
            for both.
        bounces: the scattering orders of the paths it goes with: with ≥ 1 each ray's light
            scattered once by the leaf it meets (sampled as the paths sample it) is carried to the
            next face too, and the paths leave it out; with 0 there is none to carry.
    """

    def __init__(self, field_scene, segment_ids, area_m2, *, replicates: int, seed: int, rays_per_m2, bounces: int):
        check_periodic(field_scene)
        self.rays_per_m2 = dict(zip(("sun", "sky"), check_rays(rays_per_m2)))
        self.scatter = bounces >= 1
        mi = field_scene.mi
        self.fs, self.mi, self.R, self.seed = field_scene, mi, int(replicates), int(seed)
        #: Per kind: the grid (n_a, n_b) of one replicate's rays over the cell.
        self.grid = ray_grids(field_scene.cell, self.rays_per_m2.values(), self.R)
        seg = np.asarray(segment_ids, dtype=np.int64)
        self.S = len(seg)
        # A segment without area gets no hits and 0 light, as the paths give it (not 0 × ∞).
        area = np.asarray(area_m2, dtype=np.float64)
        self._inv_area = np.divide(1.0, area, out=np.zeros_like(area), where=area > 0)
        geometry = field_scene.scene_mesh
        pos = np.minimum(np.searchsorted(seg, geometry.face_segment), len(seg) - 1)
        row = np.where(seg[pos] == geometry.face_segment, pos, _NONE).astype(np.uint32)
        normals = geometry.normals()
        self._row = owned(row, mi.UInt32)
        self._blade = owned(geometry.face_is_blade, mi.Bool)
        self._normal = mi.Vector3f(*(owned(normals[:, c].astype(np.float32), mi.Float) for c in range(3)))
        #: Per kind, the hits kept: sun key → hits (the most recently used sun last), sky → hits.
        self._kept: dict = {"sun": {}, "sky": {}}

    # -- rays ------------------------------------------------------------------------------
    def _cast(self, kind: str) -> list[Hits]:
        """All rays of ``kind``, in passes of at most :data:`CAST_CHUNK` rays."""
        gx, gy = self.grid[kind]
        n = self.R * gx * gy
        out = []
        for start in range(0, n, CAST_CHUNK):
            out += self._cast_pass(kind, start, min(CAST_CHUNK, n - start))
        return out

    def _cast_pass(self, kind: str, start: int, n: int) -> list[Hits]:
        """Rays ``start`` … ``start + n - 1`` of ``kind`` (of all replicates' R·m rays)."""
        import drjit as dr

        mi, fs, tracer = self.mi, self.fs, self.fs.tracer
        gx, gy = self.grid[kind]
        m = gx * gy
        idx = dr.opaque(mi.UInt32, start) + dr.arange(mi.UInt32, n)
        rep = idx // dr.opaque(mi.UInt32, m)
        c = idx - rep * dr.opaque(mi.UInt32, m)
        ja, jb = random_bits(mi, idx, self.seed, kind, 0)
        to_unit = 2.0**-24
        nx = dr.opaque(mi.UInt32, gx)
        ia, ib = c % nx, c // nx
        A, B = (float(v) for v in fs.cell.size_m)
        a = (mi.Float(ia) + mi.Float(ja >> 8) * to_unit) * dr.opaque(mi.Float, A / gx) - 0.5 * A
        b = (mi.Float(ib) + mi.Float(jb >> 8) * to_unit) * dr.opaque(mi.Float, B / gy) - 0.5 * B
        (ex, ey), (fx, fy) = fs.cell.axes
        cx, cy = fs.cell.center_xy
        z0 = tracer.z_top + 1e-3
        o = mi.Point3f(cx + a * ex + b * fx, cy + a * ey + b * fy, dr.full(mi.Float, z0, n))
        if kind == "sun":
            w = dr.opaque(mi.Vector3f, [float(v) for v in fs.sun])
            cap = tracer.crossings_for(fs.sun)
            weight, w0 = None, float(fs.sun[2])
        else:
            # Cosine-weighted directions: an R₂ sequence over the grid cells in tiled Z-order
            # (SKY_TILE), shifted per replicate (fixed point: exact for any index).
            s1, s2 = random_bits(mi, rep, self.seed, kind, 1)
            j = _sky_order(ia, ib, SKY_TILE) if SKY_TILE else c
            u1 = mi.Float((s1 + j * int(2**32 / _R2)) >> 8) * to_unit
            u2 = mi.Float((s2 + j * int(2**32 / _R2**2)) >> 8) * to_unit
            w = mi.Vector3f(mi.warp.square_to_cosine_hemisphere(mi.Point2f(u1, u2)))
            cap = tracer.cap
            weight, w0 = math.pi * fs.sky_radiance(w.z), 1.0
            # Evaluated here, once: left lazy, every later kernel that reads a direction (the
            # deposit, the continuation's gathers) recomputed its TEA words, seven times a pass.
            dr.eval(w, weight)
        status, o_last, maxt, _, pi = tracer.walk(o, -w, mi.Bool(True), cap=cap, soil=True, test=False)
        hit, on_soil = status == LEAF, status == SOIL
        flux_ref = fs.cell.area_m2 / m
        direct = self._deposit(hit, pi.prim_index, w, rep, weight, w0, n, flux_ref, status == CAPPED)
        if not self.scatter:
            return [direct]
        # Light scattered once on its way: at a leaf by the leaf's frozen sampling (as the paths
        # sample it), at the soil by a cosine-weighted (Lambertian) direction, and the ray
        # continued to the next face. Russian roulette: a share q of the rays goes on, carrying
        # 1/q of the flux. Only those lanes are kept (compacted): the surface interaction, the
        # sampling and the second walk cost nothing for the others.
        q = CONTINUED_SHARE[kind]
        go_on = mi.Float(random_bits(mi, idx, self.seed, kind, 4)[0] >> 8) * to_unit < q
        keep = (hit | on_soil) & go_on
        dr.eval(keep, idx, rep, hit, on_soil)  # one kernel for the mask and the gathers' sources
        sel = dr.compress(keep)
        if dr.width(sel) == 0:  # no ray of this pass goes on (a short last pass may have none)
            return [direct, *(self._no_hits(kind, part, n, flux_ref) for part in ("via_leaf", "via_soil"))]
        idx, rep, hit, on_soil, o_last, maxt, pi = (
            dr.gather(type(x), x, sel) for x in (idx, rep, hit, on_soil, o_last, maxt, pi)
        )
        if kind == "sky":
            w, weight = dr.gather(mi.Vector3f, w, sel), dr.gather(mi.Float, weight, sel)
        w0, weight = w0 / q, (None if weight is None else weight / q)
        ray = mi.Ray3f(o_last, -w)
        ray.maxt = maxt
        si = pi.compute_surface_interaction(ray, mi.RayFlags.All, hit)
        p_soil = o_last - w * maxt
        si.wi = si.to_local(w)  # towards the light
        t0, t1 = random_bits(mi, idx, self.seed, kind, 2)
        u = [mi.Float(v >> 8) * to_unit for v in (t0, t1, random_bits(mi, idx, self.seed, kind, 3)[0])]
        side, wi, wo, pdf, ok, _, _ = fs.bsdf.sample_direction(si.wi, u[0], mi.Point2f(u[1], u[2]), hit)
        o1, d1 = fs.scattered_ray(si, hit, p_soil, side, wo, mi.Point2f(u[1], u[2]))
        # One kernel for the ray and the sample the hits keep: evaluated apart, the surface
        # interaction and the sampling were computed twice (for the walk, then for the deposit).
        dr.eval(o1, d1, wi, wo, pdf, ok)
        # Only the face is needed where the scattered ray lands: no surface interaction.
        status, _, _, _, pi = tracer.walk(o1, d1, (hit & ok) | on_soil, cap=tracer.cap, soil=True, test=False)
        landed, stopped = status == LEAF, status == CAPPED
        via_leaf = self._deposit(
            landed & hit, pi.prim_index, -d1, rep, weight, w0, n, flux_ref, stopped & hit, (wi, wo, pdf, ok), "via_leaf"
        )
        via_soil = self._deposit(
            landed & on_soil, pi.prim_index, -d1, rep, weight, w0, n, flux_ref, stopped & on_soil, part="via_soil"
        )
        return [direct, via_leaf, via_soil]

    def _no_hits(self, kind: str, part: str, n: int, flux_ref: float) -> Hits:
        """An empty set of ``part``'s hits for a pass of ``n`` rays of ``kind`` (Dr.Jit refuses
        arithmetic between an empty array and a scalar, so the continuation is not run on none)."""
        mi = self.mi
        scatter = (mi.Vector3f(), mi.Vector3f(), mi.Float(), mi.Bool()) if part == "via_leaf" else None
        weight = mi.Float() if kind == "sky" else None
        return Hits(mi.UInt32(), mi.Float(), mi.Bool(), weight, 1.0, n, 0, flux_ref, scatter, part)

    def _deposit(self, hit, face, w, rep, weight, w0, n, flux_ref, capped, sample=None, part="direct") -> Hits:
        """The rays that met a requested segment's counted side (blades: both, stems: the outer),
        light arriving from ``w``, compacted."""
        import drjit as dr

        mi = self.mi
        row = dr.gather(mi.UInt32, self._row, face, hit)
        cos_n = dr.dot(dr.gather(mi.Vector3f, self._normal, face, hit), w)
        front = cos_n > 0
        ok = hit & (row != _NONE) & (front | dr.gather(mi.Bool, self._blade, face, hit))
        index, mu = row * self.R + rep, dr.abs(cos_n)
        # One kernel for what is gathered below: a gather's source is evaluated first, each in a
        # kernel of its own when left lazy.
        dr.eval(ok, index, mu, front)
        sel = dr.compress(ok)

        def take(x):
            return None if x is None else dr.gather(type(x), x, sel)

        out = Hits(
            index=take(index),
            mu=take(mu),
            front=take(front),
            weight=take(weight),
            w0=w0,
            rays=n,
            capped=0,
            flux_ref=flux_ref,
            scatter=None if sample is None else tuple(take(x) for x in sample),
            part=part,
        )
        dr.eval(out.index, out.mu, out.front, out.weight, out.scatter)
        out.capped = int(np.asarray(dr.count(capped)).sum())
        return out

    def hits(self, kind: str) -> list[Hits] | None:
        """The hits of ``kind`` ("sun": at the scene's current sun, ``None`` below the horizon;
        "sky"), cast on first use and kept: the sky's for the estimator's life, each sun's until
        :meth:`trim_suns` drops it (they depend on the sun and the seed, not on the leaf)."""
        if kind == "sun":
            if self.fs.sun[2] <= 0:
                return None
            key = _sun_key(self.fs.sun)
        else:
            key = ("sky", self.fs.sky)
        kept = self._kept[kind]
        if key in kept:
            kept[key] = kept.pop(key)  # most recently used last
        else:
            kept[key] = self._cast(kind)
        return kept[key]

    def trim_suns(self, keep=()) -> None:
        """Drop the least recently used suns' hits, except those of the sun vectors in ``keep``,
        until the kept suns' hits hold at most :data:`SUN_HITS_BUDGET_BYTES` (0: keep only
        ``keep``)."""
        trim_least_recent(self._kept["sun"], _hits_bytes, keep={_sun_key(s) for s in keep})

    def kept_suns(self) -> list[tuple[float, float, float]]:
        """The sun vectors whose hits are kept, least recently used first."""
        return [k[1:] for k in self._kept["sun"]]

    def kept_sun_bytes(self) -> dict[tuple[float, float, float], int]:
        """Bytes each kept sun's hits hold, by sun vector."""
        return {k[1:]: _hits_bytes(hs) for k, hs in self._kept["sun"].items()}

    def summary(self) -> dict:
        """What the projection cast: rays per m², the grid, and per kind kept so far the rays cast,
        the hits on requested segments and the rays stopped by the crossing cap (direct, and
        scattered once by a leaf or the soil on the way: ``via_leaf_*``, ``via_soil_*``)."""
        import drjit as dr

        out = {"replicates": self.R}
        for kind, (gx, gy) in self.grid.items():
            out[kind] = {"grid": (gx, gy), "rays_per_m2": self.R * gx * gy / self.fs.cell.area_m2}
        for key, hs in (*self._kept["sun"].items(), *self._kept["sky"].items()):
            counts = {}
            for h in hs:
                prefix = "" if h.part == "direct" else f"{h.part}_"
                if not prefix:
                    counts["rays"] = counts.get("rays", 0) + h.rays
                for name, v in (("hits", int(dr.width(h.mu))), ("capped", h.capped)):
                    counts[prefix + name] = counts.get(prefix + name, 0) + v
            out[key[0]].update(counts)
        return out

    # -- values ----------------------------------------------------------------------------
    def values(self, kind: str) -> dict[str, np.ndarray] | None:
        """Replicate values (S, R) of ``kind`` at the current leaf parameters: ``incident``,
        ``absorbed`` (per unit DNI or DHI) and their front-side shares ``incident_front``,
        ``absorbed_front``; ``None`` for the sun below the horizon."""
        import drjit as dr

        hits = self.hits(kind)
        if hits is None:
            return None
        mi = self.mi
        # The four sums of a (segment, replicate) side by side in one buffer: a hit's atomic adds
        # then meet one cache line, not four (the sky's hits land on segments in random order).
        names = ("incident", "absorbed", "incident_front", "absorbed_front")
        buf = dr.zeros(mi.UInt64, len(names) * self.S * self.R)
        with dr.suspend_grad():
            for h in hits:
                if dr.width(h.mu) == 0:  # e.g. no ray reached the soil
                    continue
                # Fixed point relative to this kind's ray flux (the same A_c/m for all its hits).
                w = self._flux(h) / hits[0].flux_ref
                a = 1.0 - leaf_albedo(self.fs.bsdf, h.mu)
                at = h.index * len(names)
                for slot, v in enumerate((w, w * a)):
                    q = mi.UInt64(mi.Float64(v) * _FIXED + 0.5)
                    dr.scatter_reduce(dr.ReduceOp.Add, buf, q, at + slot)
                    dr.scatter_reduce(dr.ReduceOp.Add, buf, q, at + (slot + 2), h.front)
            dr.eval(buf)
        sums = np.asarray(buf, dtype=np.float64).reshape(self.S, self.R, len(names))
        scale = hits[0].flux_ref / _FIXED * self._inv_area[:, None]
        return {k: sums[:, :, i] * scale for i, k in enumerate(names)}

    def _flux(self, h: Hits):
        """Each hit's flux per unit DNI or DHI, m² (Dr.Jit; at the current leaf parameters when
        the light was scattered on its way)."""
        mi, bsdf = self.mi, self.fs.bsdf
        f = h.flux_ref * (h.w0 if h.weight is None else h.weight)
        if h.soil:
            f = f * self.fs.optics.soil_albedo
        if h.scatter is not None:
            f = f * bsdf.weight(*h.scatter, mi.Bool(True))
        return mi.Float(f)

    def vjp(self, kind: str, incident: np.ndarray, absorbed: np.ndarray) -> dict[str, float]:
        """Gradient of Σ_s incident[s] · incident_s + absorbed[s] · absorbed_s (the replicates'
        means of ``kind``) w.r.t. the leaf parameters, at the current sun (zeros below the
        horizon). Incident light depends on them through the scattered rays' BSDF weight,
        absorbed light also through the albedo."""
        import drjit as dr

        grads = dict.fromkeys(LEAF_PARAMETERS, 0.0)
        mi = self.mi

        def per_hit(cotangent):
            c = np.asarray(cotangent, dtype=np.float64) * self._inv_area / self.R
            return owned(np.repeat(c, self.R), mi.Float)

        c_inc, c_abs = per_hit(incident), per_hit(absorbed)
        bsdf = self.fs.bsdf
        saved = {k: getattr(bsdf, k) for k in LEAF_PARAMETERS}
        for h in self.hits(kind) or ():
            n = dr.width(h.mu)
            if n == 0:
                continue
            # Per-hit copies of the parameters (as SegmentEstimator.vjp): an elementwise backward
            # pass, summed in float64 at the end (the same sum whatever the threads' order).
            wide = {k: dr.opaque(mi.Float, float(saved[k][0]), n) for k in LEAF_PARAMETERS}
            try:
                for k, v in wide.items():
                    dr.enable_grad(v)
                    setattr(bsdf, k, v)
                a = 1.0 - leaf_albedo(bsdf, h.mu)
                c = dr.gather(mi.Float, c_inc, h.index) + dr.gather(mi.Float, c_abs, h.index) * a
                loss = c * self._flux(h)
                dr.backward(dr.sum(loss))
                for k, v in wide.items():
                    grads[k] += sum_float64(dr.grad(v))
            finally:
                for k, v in saved.items():
                    setattr(bsdf, k, v)
        return grads
