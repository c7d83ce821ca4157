r"""Ray transport through a periodic cell: every ray of the estimator sees an infinite field.

The field is one :class:`~lightfit.plant.periodic.PeriodicCell` repeated without end
(docs/light.md, "Periodic boundary"). A ray is traced in *segments*, each confined to the cell
box (the cell's rectangle × all heights):

1. its origin is wrapped into the cell (moved by whole lattice vectors);
2. it is intersected with the scene up to the nearest of: the exit through a side face of the
   box (distance :math:`t_{exit}`) and, for rays going down, the analytic soil plane z = 0;
3. a hit before that ends it on a leaf or stem; reaching the soil first ends it on the soil;
   leaving the box above the canopy top :math:`z_{top}` (the highest vertex), going up, ends it
   in the sky;
4. otherwise it re-enters through the opposite side face — its exit point shifted by minus the
   period of each face it crossed (both at a corner) — and the next segment starts there.

Only hits inside the box are accepted (step 2 clips the ray at the box), so geometry reaching
over a side face must be present inside the box as a copy: the scene holds the periodic
images of every face (:meth:`PeriodicCell.images`), keeping its segment id. This is how HELIOS
and LESS move rays (docs/design.md §7), with the overhanging parts of the plants kept (LESS
loses them).

**Crossing cap.** A ray that has made C crossings without leaving the layer 0 ≤ z ≤ z_top has
travelled at least :math:`D_C = (C - 2)/\sqrt{A^{-2} + B^{-2}}` horizontally (each period A, B
is crossed at most once per its length, +1 at either end), so its elevation e satisfies
:math:`\tan|e| \le z_{top}/D_C`. Rays drawn from a cosine lobe about any normal put at most a
share :math:`\tfrac{4}{\pi}|e|` of their weight within ±e of the horizon (the worst case is a
vertical surface; about the vertical the share is sin²e). So capping at

.. math:: C = 2 + \left\lceil \frac{4}{\pi}\,\frac{z_{top}\sqrt{A^{-2}+B^{-2}}}{\tau} \right\rceil

truncates at most a share τ of the light of any scattering order, before counting the canopy
itself, which stops almost every near-horizontal ray within a few metres (that is why the cap
is cheap: the loop runs per lane, inside one kernel, only as long as each ray needs). A capped
ray counts as blocked (shadow rays) or as carrying no light (paths), as in HELIOS: the bias is
one-sided and bounded by τ; the estimator reports how many rays hit the cap. Shadow rays to the
sun have a fixed direction, so their exact maximum number of crossings is known
(:meth:`PeriodicTracer.crossings_for`) and they are never truncated (up to
:data:`MAX_SUN_CROSSINGS`).

Everything here is geometry, detached from the leaf parameters: gradients (PRB, the BSDF
weights) are unaffected.
"""

from __future__ import annotations

import math

import numpy as np

from lightfit.errors import InputError
from lightfit.light.backend import mitsuba
from lightfit.plant.periodic import PeriodicCell

#: Default tolerance τ: share of any scattering order's light that the crossing cap may truncate.
DEFAULT_CROSSING_TOLERANCE = 1e-3
#: Hard limit for shadow rays to a grazing sun (0.05° elevation over a 1 m canopy in a 0.3 m cell
#: is ≈ 4 000 crossings); beyond it a sun ray counts as blocked and is reported as capped.
MAX_SUN_CROSSINGS = 100_000
#: Ray status after a walk.
INACTIVE, RUNNING, LEAF, SOIL, SKY, CAPPED = range(6)


def crossing_cap(cell: PeriodicCell, z_top: float, tolerance: float = DEFAULT_CROSSING_TOLERANCE) -> int:
    """Crossing cap C for a cell and canopy top ``z_top`` (m, the height rays start from) so that
    truncated light ≤ ``tolerance`` (a fraction; module doc)."""
    if not 0 < tolerance < 1:
        raise InputError(
            f"crossing tolerance={tolerance!r}", parameter="crossing_tolerance", expected="a number in (0, 1)"
        )
    a, b = cell.size_m
    return 2 + math.ceil(4 / math.pi * max(z_top, 0.0) * math.sqrt(a**-2 + b**-2) / tolerance)


class PeriodicTracer:
    """Ray casting in a periodic cell, for :class:`~lightfit.light.scene.FieldScene`.

    Args:
        scene: the Mitsuba scene, holding the periodic images of the mesh.
        cell: the periodic cell.
        z_top: canopy top, m (highest vertex): above it a ray going up meets nothing more.
        tolerance: τ for :func:`crossing_cap`.
    """

    def __init__(self, scene, cell: PeriodicCell, z_top: float, tolerance: float = DEFAULT_CROSSING_TOLERANCE):
        self.mi, self.scene, self.cell = mitsuba(), scene, cell
        self.z_top = float(z_top)
        self.tolerance = float(tolerance)
        self.cap = crossing_cap(cell, self.z_top, tolerance)

    def crossings_for(self, direction: np.ndarray) -> int:
        """Most crossings a ray going up in fixed ``direction`` can make between z = 0 and z_top."""
        d = np.asarray(direction, dtype=np.float64)
        if d[2] <= 0:
            return self.cap
        ea, eb = self.cell.axes
        run = self.z_top / d[2]  # path length from the soil to the canopy top
        n = sum(math.ceil(run * abs(float(d[:2] @ e)) / p) for e, p in zip((ea, eb), self.cell.size_m))
        return int(min(n + 2, MAX_SUN_CROSSINGS))

    # -- Dr.Jit ----------------------------------------------------------------------------
    def _constants(self, T=None) -> dict:
        """The cell as *opaque* Dr.Jit scalars of type ``T`` (default ``mi.Float``): kernels then do
        not depend on the cell, canopy height or cap, so one compiled walk serves every scene, sun
        and bounce (and is cached on disk); with literals, every scene compiled its own loops
        (seconds per render)."""
        T = self.mi.Float if T is None else T
        cache = self.__dict__.setdefault("_c", {})
        if T not in cache:
            import drjit as dr

            (ex, ey), (fx, fy) = self.cell.axes
            A, B = (float(p) for p in self.cell.size_m)
            cx, cy = (float(c) for c in self.cell.center_xy)
            vals = dict(A=A, B=B, ex=ex, ey=ey, fx=fx, fy=fy, cx=cx, cy=cy, z_top=self.z_top)
            cache[T] = {k: dr.opaque(T, float(v)) for k, v in vals.items()}
        return cache[T]

    def _local(self, o):
        """Cell-frame coordinates (a, b) of Dr.Jit points."""
        c = self._constants()
        x, y = o.x - c["cx"], o.y - c["cy"]
        return x * c["ex"] + y * c["ey"], x * c["fx"] + y * c["fy"]

    def _shift(self, o, i, j):
        """``o`` moved by the lattice vector i·A·ê_a + j·B·ê_b (i, j Dr.Jit floats)."""
        c = self._constants()
        ia, jb = i * c["A"], j * c["B"]
        return self.mi.Point3f(o.x + ia * c["ex"] + jb * c["fx"], o.y + ia * c["ey"] + jb * c["fy"], o.z)

    def wrap(self, o):
        """Dr.Jit points moved by whole lattice vectors into the cell."""
        import drjit as dr

        c = self._constants()
        a, b = self._local(o)
        return self._shift(o, -dr.floor(a / c["A"] + 0.5), -dr.floor(b / c["B"] + 0.5))

    def wrap64(self, x):
        """Points given as three Dr.Jit Float64 arrays (x, y, z), m, moved by whole lattice vectors
        into the cell: the arithmetic of :meth:`PeriodicCell.wrap` (numpy), in float64, with the
        cell as opaque constants (one compiled kernel for every cell). A point exactly on a side
        face may be put on the other side than numpy puts it (its matrix product may round the
        cell-frame coordinate differently): the same point of the infinite field."""
        import drjit as dr

        c = self._constants(self.mi.Float64)
        # Not _local/_shift: their float32 order of operations differs from numpy's.
        px, py = x[0] - c["cx"], x[1] - c["cy"]
        i = -dr.floor((px * c["ex"] + py * c["ey"]) / c["A"] + 0.5)
        j = -dr.floor((px * c["fx"] + py * c["fy"]) / c["B"] + 0.5)
        ia, jb = i * c["A"], j * c["B"]
        out = (i != 0) | (j != 0)
        shift = (ia * c["ex"] + jb * c["fx"], ia * c["ey"] + jb * c["fy"])
        return [dr.select(out, p + s, p) for p, s in zip(x[:2], shift)] + [x[2]]

    def walk(self, o, d, active, *, cap: int, soil: bool, test: bool, fuse: bool = False):
        """Trace rays segment by segment through the cell (module doc) in one symbolic loop.

        Args:
            o, d: origins (anywhere; wrapped first) and unit directions (Dr.Jit, detached).
            active: lanes to trace.
            cap: most crossings before a ray counts as :data:`CAPPED`.
            soil: stop rays going down at the soil plane z = 0.
            test: shadow rays (``ray_test``: any hit) instead of nearest hits.
            fuse: leave the walk unevaluated, to be fused into the caller's kernel (a primal
                render evaluates as one kernel; docs/light.md, "Ray wrapping"). Otherwise inputs and
                outputs are evaluated and the walk is its own kernel, the same for every bounce
                (what a differentiated render needs: its backward kernels would recompute an
                unevaluated walk each time they read it).

        Returns:
            ``(status, origin, maxt, crossings, pi)``: per lane the :data:`INACTIVE` …
            :data:`CAPPED` status, the origin and length limit of its last segment, the number
            of crossings made, and (``test=False``) Mitsuba's preliminary intersection of the
            hit, relative to that last segment.
        """
        mi, scene = self.mi, self.scene
        import drjit as dr

        c = self._constants()
        A2, B2, z_top = c["A"] * 0.5, c["B"] * 0.5, c["z_top"]
        cap = dr.opaque(mi.UInt32, int(cap))
        o, d = mi.Point3f(dr.detach(o)), mi.Vector3f(dr.detach(d))
        n = dr.width(o)
        active = mi.Bool(active) & dr.full(mi.Bool, True, n)
        if not fuse:
            dr.make_opaque(o, d, active)
        da, db = d.x * c["ex"] + d.y * c["ey"], d.x * c["fx"] + d.y * c["fy"]
        inf = dr.inf
        o = self.wrap(o)
        status = dr.select(active, mi.UInt32(RUNNING), mi.UInt32(INACTIVE))
        maxt = dr.zeros(mi.Float, n)
        k = dr.zeros(mi.UInt32, n)
        # The hit found inside the loop is kept: no second traversal to find it again.
        pi = dr.zeros(mi.PreliminaryIntersection3f, 1 if test else n)

        def exit_distance(u, du, half):
            t = dr.select(du > 0, (half - u) / du, dr.select(du < 0, (-half - u) / du, inf))
            return dr.maximum(t, 0.0)

        def body(o, status, maxt, k, pi):
            running = status == RUNNING
            a, b = self._local(o)
            ta, tb = exit_distance(a, da, A2), exit_distance(b, db, B2)
            t_exit = dr.minimum(ta, tb)
            t_soil = dr.select(d.z < 0, dr.maximum(-o.z / d.z, 0.0), inf) if soil else mi.Float(inf)
            t_max = dr.minimum(t_exit, t_soil)
            ray = mi.Ray3f(o, d)
            ray.maxt = t_max
            if test:
                hit = running & scene.ray_test(ray, running)
            else:
                pi_new = scene.ray_intersect_preliminary(ray, False, running)
                hit = running & pi_new.is_valid()
                pi = dr.select(hit, pi_new, pi)
            on_soil = running & ~hit & (t_soil <= t_exit)
            # Going up and leaving the box above the canopy top: nothing further can be hit.
            up = running & ~hit & ~on_soil & (d.z > 0) & (o.z + t_exit * d.z >= z_top)
            cross = running & ~hit & ~on_soil & ~up
            capped = cross & (k >= cap)
            cross &= ~capped
            U = mi.UInt32
            new = dr.select(
                hit,
                U(LEAF),
                dr.select(on_soil, U(SOIL), dr.select(up, U(SKY), dr.select(capped, U(CAPPED), U(RUNNING)))),
            )
            # Re-enter through the opposite face(s): the exit point moved by minus the period
            # of each face crossed (both at a corner).
            i = dr.select(ta <= t_exit, dr.select(da > 0, -1.0, 1.0), 0.0)
            j = dr.select(tb <= t_exit, dr.select(db > 0, -1.0, 1.0), 0.0)
            nxt = self._shift(o + d * t_exit, i, j)
            o = dr.select(cross, nxt, o)
            maxt = dr.select(running & ~cross, t_max, maxt)
            k = dr.select(cross, k + 1, k)
            status = dr.select(running, new, status)
            return o, status, maxt, k, pi

        o, status, maxt, k, pi = dr.while_loop(
            state=(o, status, maxt, k, pi), cond=lambda o, status, maxt, k, pi: status == RUNNING, body=body
        )
        if not fuse:
            dr.eval(o, status, maxt, k, pi)
        return status, o, maxt, k, pi

    def intersect(self, o, d, active, cap: int | None = None, fuse: bool = False):
        """Nearest hit of path rays: ``(hit_leaf, si, hit_soil, p_soil, escaped, capped, crossings)``.

        ``si`` is Mitsuba's full surface interaction of the leaf hit (valid where ``hit_leaf``),
        ``p_soil`` the soil point (where ``hit_soil``), both inside the cell.
        """
        mi = self.mi
        status, o_last, maxt, k, pi = self.walk(
            o, d, active, cap=self.cap if cap is None else cap, soil=True, test=False, fuse=fuse
        )
        hit_leaf = status == LEAF
        ray = mi.Ray3f(o_last, mi.Vector3f(d))
        ray.maxt = maxt
        si = pi.compute_surface_interaction(ray, mi.RayFlags.All, hit_leaf)
        hit_soil = status == SOIL
        return hit_leaf, si, hit_soil, o_last + d * maxt, status == SKY, status == CAPPED, k

    def occluded(self, o, d, active, cap: int, fuse: bool = False):
        """Shadow rays: ``(blocked, capped, crossings)``; a capped ray counts as blocked."""
        status, _, _, k, _ = self.walk(o, d, active, cap=cap, soil=False, test=True, fuse=fuse)
        capped = status == CAPPED
        return (status == LEAF) | capped, capped, k
