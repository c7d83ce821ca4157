r"""Identifiability: Fisher information, stiff/sloppy directions, profile likelihood.

For whitened residuals :math:`r(x) = (y - m(x))/\sqrt v` (Gaussian likelihood, variance treated
as fixed) the Fisher information at :math:`\hat x` is :math:`F = J^\top J`, :math:`J = \partial r/\partial x`
from ``jax.jacrev`` (reverse mode works through the Mitsuba bridge and the emulator alike). Its
eigenvectors are the parameter combinations the data constrain: the largest eigenvalue is the
*stiffest* combination (its 1σ width ≈ 1/√λ), the smallest the *sloppiest*. Coordinates:
``scale="log"`` uses log-parameters (relative changes, the usual choice in sloppy-model analyses;
eigenvector entries then read as exponents of a product of parameters), ``"natural"`` the
parameters themselves.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from lightfit.errors import InputError


@dataclass
class FisherResult:
    """Fisher matrix (in the chosen coordinates), eigenvalues (descending) and eigenvectors (columns,
    each oriented as :func:`combination` writes it: its largest entry positive)."""

    names: tuple
    x: np.ndarray
    scale: str
    fisher: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray

    @property
    def stiff(self) -> str:
        return combination(self.eigenvectors[:, 0], self.names, self.scale)

    @property
    def sloppy(self) -> str:
        return combination(self.eigenvectors[:, -1], self.names, self.scale)

    @property
    def widths(self) -> np.ndarray:
        """1σ widths along each eigenvector, 1/√λ (inf for λ ≤ 0; eigenvalues within eigh's round-off
        of 0, n·eps·λ_max, are 0)."""
        lam = np.asarray(self.eigenvalues)
        return np.where(lam > 0, 1.0 / np.sqrt(np.maximum(lam, 1e-300)), np.inf)

    def table(self) -> list[dict]:
        return [
            {
                "eigenvalue": float(ev),
                "width_1sigma": float(w),  # inf where the data say nothing (eigenvalue 0)
                "width_scale": self.scale,  # the width's units: log parameter, or the parameter's own
                "combination": combination(v, self.names, self.scale),
            }
            for ev, w, v in zip(self.eigenvalues, self.widths, self.eigenvectors.T)
        ]


def oriented(vec) -> np.ndarray:
    """``vec`` (one direction, or directions as columns) with each one's largest-magnitude entry
    positive, as :func:`combination` writes it (an all-zero one as it is): a direction and its
    opposite are one combination, and eigh's sign is arbitrary."""
    vec = np.asarray(vec, float)
    cols = vec.reshape(len(vec), -1)
    sign = np.sign(cols[np.argmax(np.abs(cols), axis=0), np.arange(cols.shape[1])])
    return (cols * np.where(sign == 0, 1.0, sign)).reshape(vec.shape)


def combination(vec, names, scale: str = "log") -> str:
    """Human-readable combination, e.g. ``+0.71 log specular −0.70 log subsurface`` (|entry| ≥ 0.1)."""
    vec = oriented(vec)
    pre = "log " if scale == "log" else ""
    terms = [f"{v:+.2f} {pre}{n}" for v, n in sorted(zip(vec, names), key=lambda t: -abs(t[0])) if abs(v) >= 0.1]
    return " ".join(terms)


def fisher_information(residuals, x0, names, scale: str = "log") -> FisherResult:
    """Fisher information of whitened ``residuals(x) -> (n,)`` at ``x0`` (natural parameters).

    The Jacobian is taken by ``jax.jacrev``; with ``scale="log"`` with respect to log x
    (requires x0 > 0).
    """
    x0 = np.asarray(x0, float)
    names = tuple(names)
    if x0.shape != (len(names),):
        raise InputError(f"x0 shape {x0.shape}", parameter="x0", expected=f"({len(names)},) — one value per name")
    if not np.all(np.isfinite(x0)):  # NaN passed the log scale's "> 0" test: a Fisher matrix of NaN
        bad = [n for n, v in zip(names, x0) if not np.isfinite(v)]
        raise InputError(f"non-finite value(s) of {bad}", parameter="x0", expected="finite values")
    if scale == "log":
        if np.any(x0 <= 0):
            bad = [n for n, v in zip(names, x0) if v <= 0]
            raise InputError(f"non-positive value(s) of {bad}", parameter="x0", expected="> 0 for scale='log'")
        jac = jax.jacrev(lambda lx: residuals(jnp.exp(lx)))(jnp.log(jnp.asarray(x0)))
    elif scale == "natural":
        jac = jax.jacrev(residuals)(jnp.asarray(x0))
    else:
        raise InputError(f"scale={scale!r}", parameter="scale", expected="'log' or 'natural'")
    J = np.asarray(jac, float)
    if not np.all(np.isfinite(J)):  # eigh of a NaN matrix: NaN eigenvalues, or LinAlgError, unsaid
        cols = [n for n, ok in zip(names, np.all(np.isfinite(J), axis=0)) if not ok]
        raise InputError(
            f"the residuals' Jacobian at x0={x0.tolist()} is not finite with respect to {cols}",
            parameter="x0",
            expected="a point where the model and its residuals are finite (e.g. photosynthesis converged)",
        )
    F = J.T @ J
    lam, vec = np.linalg.eigh(F)
    # eigh's round-off, |δλ| ≲ n·eps·λ_max (numpy's matrix_rank tolerance): a direction the residuals do
    # not depend on came out as ±1e-17·λ_max, a 1σ width of 10⁶ (or ∞) by chance of the sign; it is 0
    lam = np.where(np.abs(lam) <= len(lam) * np.finfo(float).eps * max(float(np.max(lam)), 0.0), 0.0, lam)
    order = np.argsort(lam)[::-1]
    lam, vec = lam[order], vec[:, order]
    # each eigenvector oriented as combination() writes it (its largest entry positive): eigh's sign is
    # arbitrary, and a profile stored along a column read as the combination's string was mirrored
    vec = oriented(vec)
    return FisherResult(names, x0, scale, F, lam, vec)


def _checked_line(x_hat, direction, scale: str) -> tuple[np.ndarray, np.ndarray]:
    """``x_hat`` and the unit ``direction`` as float arrays, or :class:`InputError`: a scale other than
    "log" and "natural" (it was taken for "natural" unsaid), a point that is not finite (or not > 0
    in log coordinates), a direction of another length (JAX's broadcast error), zero or not finite
    (a profile of NaN)."""
    if scale not in ("log", "natural"):
        raise InputError(f"scale={scale!r}", parameter="scale", expected="'log' or 'natural'")
    x_hat = np.asarray(x_hat, float)
    d = np.asarray(direction, float)
    if x_hat.ndim != 1 or not np.all(np.isfinite(x_hat)) or (scale == "log" and np.any(x_hat <= 0)):
        raise InputError(
            f"x_hat={x_hat.tolist()}",
            parameter="x_hat",
            expected="a vector of finite values" + (", each > 0 for scale='log'" if scale == "log" else ""),
        )
    if d.shape != x_hat.shape or not np.all(np.isfinite(d)) or not np.any(d != 0):
        raise InputError(
            f"direction={d.tolist()}",
            parameter="direction",
            expected=f"{len(x_hat)} finite values, not all 0 (one per parameter of x_hat)",
        )
    return x_hat, d / np.linalg.norm(d)


def _box(box, shape, scale: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``box`` (``(lo, hi)`` in the parameters' units) broadcast to ``shape``: its bounds in x and in
    u (log x or x; a bound at 0 is −∞ in log x)."""
    lo, hi = (np.broadcast_to(np.asarray(b, float), shape) for b in box)
    with np.errstate(divide="ignore"):
        lo_u, hi_u = (np.log(lo), np.log(hi)) if scale == "log" else (lo, hi)
    return lo, hi, lo_u, hi_u


def offsets_in_box(x_hat, direction, box, scale: str = "log") -> tuple[float, float]:
    r"""The offsets t of :func:`profile_likelihood` whose hyperplane :math:`d\cdot(u - \hat u) = t` meets
    ``box`` (``(lo, hi)`` in the parameters' units, ±∞ where unbounded; u = log x or x, d the unit
    ``direction``): :math:`[\sum_i \min(d_i l_i, d_i h_i),\ \sum_i \max(d_i l_i, d_i h_i)] - d\cdot\hat u`
    over the box's bounds l, h in u. Outside it the profile is +∞ (no point of the box to optimise)."""
    x_hat, d = _checked_line(x_hat, direction, scale)
    _, _, lo_u, hi_u = _box(box, x_hat.shape, scale)
    with np.errstate(invalid="ignore"):  # 0 · ∞, taken out below
        a, b = d * lo_u, d * hi_u
    a, b = np.where(d == 0, 0.0, a), np.where(d == 0, 0.0, b)  # a direction without x_i: its bounds do not count
    c = float(d @ (np.log(x_hat) if scale == "log" else x_hat))
    return float(np.minimum(a, b).sum()) - c, float(np.maximum(a, b).sum()) - c


def profile_likelihood(
    nll, x_hat, direction, ts, *, scale: str = "log", box=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Profile of ``nll(x)`` along ``direction`` through ``x_hat``.

    At each offset t the parameters are :math:`u = u(\hat x) + t\,d + P_\perp w` (u = log x or x;
    d the unit vector along ``direction``, so t is a distance in u), and w (orthogonal to d) is
    optimised (scipy BFGS with JAX gradients; within ``box`` scipy SLSQP with the box as linear
    constraints; warm-started from the neighbouring t).
    ``box`` (``(lo, hi)`` in the parameters' units, inclusive, ±∞ where unbounded; ``None``:
    everywhere) keeps the optimised points where ``nll`` may be evaluated, e.g. an emulator's box:
    outside it the objective is +∞. A warm start outside the box is
    first moved to the box's point nearest it on the offset's hyperplane (through a box's corner the
    line leaves the box at once, and every start outside it stayed there at +∞); the profile is +∞ at
    an offset with no point in the box (the slice itself is evaluated wherever the line goes, and
    counts for the profile only inside). Returns ``(ts, profile, slice)``: the profiled and the
    plain-slice nll.
    """
    from scipy.optimize import minimize

    x_hat, d = _checked_line(x_hat, direction, scale)
    u0 = np.log(x_hat) if scale == "log" else x_hat
    to_x = (lambda u: jnp.exp(u)) if scale == "log" else (lambda u: u)
    # orthonormal basis of the complement of d
    q, _ = np.linalg.qr(np.column_stack([d, np.eye(len(d))]))
    basis = q[:, 1 : len(d)]
    ts = np.asarray(ts, float)
    if ts.ndim != 1 or not np.all(np.isfinite(ts)):
        raise InputError(f"ts={ts.tolist()}", parameter="ts", expected="a vector of finite offsets")
    if box is not None:
        lo, hi, lo_u, hi_u = _box(box, x_hat.shape, scale)
        width = hi_u - lo_u
        hair = 1e-9 * np.where(np.isfinite(width), width, 1.0)  # strictly inside after round-off
        lo_u, hi_u = lo_u + hair, hi_u - hair

    def inside(x):
        return True if box is None else jnp.all((x >= lo) & (x <= hi))

    def into_box(u, t):
        """The point clip(u + λd) of the (hair-shrunk) box on the offset's hyperplane d·(u − u₀) = t,
        found by bisection in λ (d·clip(u + λd) rises with λ), or ``None`` where the plane misses it."""

        def h(lam):
            return d @ (np.clip(u + lam * d, lo_u, hi_u) - u0) - t

        a, b = -1.0, 1.0
        while h(a) > 0 and a > -1e12:
            a *= 2
        while h(b) < 0 and b < 1e12:
            b *= 2
        if h(a) > 0 or h(b) < 0:
            return None
        for _ in range(200):
            m = 0.5 * (a + b)
            a, b = (m, b) if h(m) < 0 else (a, m)
        return np.clip(u + b * d, lo_u, hi_u)

    def f_w(w, t):
        return nll(to_x(jnp.asarray(u0 + t * d) + jnp.asarray(basis) @ w))

    def f_inside(w, t):
        x = to_x(jnp.asarray(u0 + t * d) + jnp.asarray(basis) @ w)
        return jnp.where(inside(x), f_w(w, t), jnp.inf)

    vg = jax.jit(jax.value_and_grad(f_inside))
    f_j = jax.jit(f_w)
    prof, slc = np.empty(len(ts)), np.empty(len(ts))
    order = np.argsort(np.abs(ts))
    w = np.zeros(basis.shape[1])
    last = {}

    for i in order:
        t = ts[i]
        slc[i] = float(f_j(jnp.zeros(basis.shape[1]), t))
        on_slice = slc[i] if bool(inside(to_x(jnp.asarray(u0 + t * d)))) else np.inf  # no extrapolation
        # warm start from the nearest already-solved offset on the same side
        near = [j for j in last if np.sign(ts[j]) == np.sign(t) or ts[j] == 0]
        w0 = last[min(near, key=lambda j: abs(ts[j] - t))] if near else w
        start = u0 + t * d + basis @ w0
        if not bool(inside(to_x(jnp.asarray(start)))):
            moved = into_box(start, t)
            w0 = w0 if moved is None else basis.T @ (moved - u0 - t * d)

        def fun(wv, t=t):
            v, g = vg(jnp.asarray(wv), t)
            v, g = float(v), np.asarray(g, float)
            return (v, g) if np.isfinite(v) else (1e30, np.zeros_like(g))

        if basis.shape[1] and box is not None:
            # the box as linear constraints on w (lo ≤ u0 + td + Bw ≤ hi where finite): BFGS against
            # the +∞ outside stopped on the first face it met, unable to slide along it, and left the
            # profile up to 7 nll units above its minimum on a real run (optimum on the box's edge)
            c = u0 + t * d
            lo_f, hi_f = np.isfinite(lo_u), np.isfinite(hi_u)
            a_mat = np.vstack([basis[lo_f], -basis[hi_f]])
            b_vec = np.concatenate([lo_u[lo_f] - c[lo_f], c[hi_f] - hi_u[hi_f]])
            cons = [{"type": "ineq", "fun": lambda wv, a=a_mat, b=b_vec: a @ wv - b, "jac": lambda wv, a=a_mat: a}]
            r = minimize(
                fun,
                w0,
                jac=True,
                method="SLSQP",
                constraints=cons if len(b_vec) else (),
                options={"maxiter": 200, "ftol": 1e-12},
            )
            last[i] = r.x
            prof[i] = min(r.fun, on_slice) if r.fun < 1e30 else on_slice  # 1e30: nowhere finite
        elif basis.shape[1]:
            r = minimize(fun, w0, jac=True, method="BFGS", options={"maxiter": 200, "gtol": 1e-6})
            last[i] = r.x
            prof[i] = min(r.fun, on_slice) if r.fun < 1e30 else on_slice  # 1e30: nowhere finite
        else:
            prof[i] = on_slice
    return ts, prof, slc


__all__ = ["FisherResult", "combination", "fisher_information", "offsets_in_box", "profile_likelihood"]
