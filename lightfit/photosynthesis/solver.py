r"""Elementwise scalar root finding for the per-segment CO2 balance.

Every segment has its own scalar equation :math:`r(x) = 0`, so the solvers below work on
whole arrays at once (each element independently, loop until all are done) and derivatives
are obtained with one forward-mode product against a vector of ones (the Jacobian is
diagonal).

:func:`bracketed_newton` is Newton's method safeguarded by bisection on a bracket
:math:`[lo, hi]` with :math:`r(lo) \le 0 \le r(hi)` (``rtsafe``, Press et al., Numerical
Recipes, §9.4): a Newton step is taken only when it stays inside the bracket and the
residual shrinks fast enough, otherwise the bracket is halved. For a continuous residual
this always converges, also where plain fixed-point iteration oscillates.

:func:`fixed_point_iteration` is the plain iteration :math:`x \leftarrow g(x)` kept as the
baseline for benchmarks and for demonstrating its failures.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.typing import DTypeLike

from lightfit.errors import check_integer, check_real


class SolverConfig(eqx.Module):
    """Tolerances of the CO2 solve (all static).

    An element is converged when its last step, its predicted Newton correction
    ``|r/r'|`` or its bracket is below ``atol_umol_mol + rtol·|x|`` *and*, where the caller
    gives a residual scale ``s`` (the CO2 solve does: ``s = |An| + Rd + |g_tot·(ca − cc)|``),
    the residual itself is below ``flux_atol_umol_m2_s + flux_rtol·s``. The second test
    matters at kinks of the residual: where its slope is huge (Tuzet/Leuning with cs near
    Γ*), ``|r/r'|`` is tiny although the CO2 balance is far from closed.

    Attributes:
        rtol: relative tolerance on the chloroplast CO2 mole fraction [-].
        atol_umol_mol: absolute tolerance [µmol mol⁻¹].
        max_steps: iteration cap; elements not converged by then are flagged.
        flux_rtol: relative tolerance on the residual (CO2 balance) [-].
        flux_atol_umol_m2_s: absolute tolerance on the residual [µmol m⁻² s⁻¹].
    """

    rtol: float = eqx.field(static=True, default=1e-11)
    atol_umol_mol: float = eqx.field(static=True, default=1e-9)
    max_steps: int = eqx.field(static=True, default=100)
    flux_rtol: float = eqx.field(static=True, default=1e-7)
    flux_atol_umol_m2_s: float = eqx.field(static=True, default=1e-9)

    def __check_init__(self):
        # a negative tolerance or no step at all only ever reported "unconverged", with no word why
        for name in ("rtol", "atol_umol_mol", "flux_rtol", "flux_atol_umol_m2_s"):
            check_real(getattr(self, name), f"SolverConfig.{name}", 0.0, expected="a finite tolerance ≥ 0")
        check_integer(self.max_steps, "SolverConfig.max_steps", 1, why="iterations of the CO2 solve")

    @classmethod
    def for_dtype(cls, dtype: DTypeLike, max_steps: int = 100) -> SolverConfig:
        """Default tolerances for ``dtype``: 1e-11 relative in float64, 2e-6 in float32 (on cc);
        1e-7 and 1e-3 relative on the residual."""
        if jnp.finfo(dtype).bits >= 64:
            return cls(rtol=1e-11, atol_umol_mol=1e-9, max_steps=max_steps, flux_rtol=1e-7, flux_atol_umol_m2_s=1e-9)
        return cls(rtol=2e-6, atol_umol_mol=1e-4, max_steps=max_steps, flux_rtol=1e-3, flux_atol_umol_m2_s=1e-4)


class RootResult(NamedTuple):
    """Root, per-element convergence flag and iteration count."""

    x: jax.Array
    converged: jax.Array
    iterations: jax.Array


def _value_and_slope(fn, x, args):
    return jax.jvp(lambda y: fn(y, args), (x,), (jnp.ones_like(x),))


def bracketed_newton(
    fn: Callable[[jax.Array, Any], jax.Array],
    x0: jax.Array,
    lo: jax.Array,
    hi: jax.Array,
    args: Any,
    config: SolverConfig,
    residual_scale: Callable[[jax.Array, Any], jax.Array] | None = None,
) -> RootResult:
    """Safeguarded Newton on ``fn(x, args) = 0`` elementwise, given ``fn(lo) <= 0 <= fn(hi)``.

    Args:
        fn: elementwise residual ``(x, args) -> r`` (same shape as ``x``).
        x0: initial guess inside ``[lo, hi]``.
        lo, hi: bracket.
        args: PyTree passed through to ``fn``.
        config: :class:`SolverConfig`.
        residual_scale: optional ``(x, args) -> s`` (≥ 0, same shape as ``x``); if given an
            element also needs ``|r| <= config.flux_atol_umol_m2_s + config.flux_rtol·s`` to
            count as converged (see :class:`SolverConfig`).

    Returns:
        :class:`RootResult`; ``converged`` is False where the cap was hit or the residual
        was not finite. A step or bracket shrunk below the tolerance counts only once residuals
        of both signs have been seen: on a bracket without a sign change (``fn(lo) > 0``, no
        root) the bisection shrank onto its end and reported it converged.
    """

    def small_residual(x, r):
        if residual_scale is None:
            return jnp.ones(jnp.shape(r), bool)
        return jnp.abs(r) <= config.flux_atol_umol_m2_s + config.flux_rtol * residual_scale(x, args)

    x0 = jnp.clip(x0, lo, hi)
    r0, d0 = _value_and_slope(fn, x0, args)
    lo = jnp.where(r0 < 0, x0, lo)
    hi = jnp.where(r0 > 0, x0, hi)
    width = hi - lo
    done0 = (
        (jnp.abs(r0) <= (config.atol_umol_mol + config.rtol * jnp.abs(x0)) * jnp.abs(d0))
        & jnp.isfinite(r0)
        & small_residual(x0, r0)
    )
    zeros = jnp.zeros(x0.shape, jnp.int32)
    signs = (r0 <= 0, r0 >= 0)
    init = (x0, r0, d0, lo, hi, width, width, signs, done0, zeros, jnp.asarray(0, jnp.int32))

    def cond(state):
        *_, done, _, step = state
        return (step < config.max_steps) & ~jnp.all(done)

    def body(state):
        x, r, d, lo, hi, dx_last, dx_prev, (seen_neg, seen_pos), done, n, step = state
        newton = x - r / d
        inside = (newton - lo) * (newton - hi) < 0
        fast = jnp.abs(2.0 * r) <= jnp.abs(dx_prev * d)
        use_newton = inside & fast & jnp.isfinite(newton)
        x_new = jnp.where(use_newton, newton, 0.5 * (lo + hi))
        dx = x_new - x
        r_new, d_new = _value_and_slope(fn, x_new, args)
        active = ~done
        lo_new = jnp.where(active & (r_new < 0), x_new, lo)
        hi_new = jnp.where(active & (r_new > 0), x_new, hi)
        tol = config.atol_umol_mol + config.rtol * jnp.abs(x_new)
        # The predicted Newton correction |r/r'| is the error estimate once Newton has
        # converged; the bisection fallback would otherwise take over at round-off level.
        predicted = jnp.abs(r_new) <= tol * jnp.abs(d_new)
        seen_neg, seen_pos = seen_neg | (r_new <= 0), seen_pos | (r_new >= 0)
        shrunk = seen_neg & seen_pos & ((jnp.abs(dx) <= tol) | (hi_new - lo_new <= tol))
        finished = jnp.isfinite(r_new) & (predicted | shrunk) & small_residual(x_new, r_new)

        def upd(new, old):
            return jnp.where(active, new, old)

        return (
            upd(x_new, x),
            upd(r_new, r),
            upd(d_new, d),
            lo_new,
            hi_new,
            upd(dx, dx_last),
            upd(dx_last, dx_prev),
            (seen_neg, seen_pos),
            done | (active & finished),
            n + active.astype(jnp.int32),
            step + 1,
        )

    x, r, _, _, _, _, _, _, done, n, _ = jax.lax.while_loop(cond, body, init)
    return RootResult(x, done & jnp.isfinite(r), n)


def fixed_point_iteration(
    g: Callable[[jax.Array, Any], jax.Array], x0: jax.Array, args: Any, config: SolverConfig
) -> RootResult:
    """Plain iteration ``x <- g(x, args)`` elementwise (baseline; no safeguard).

    Converged where ``|g(x) - x| <= atol + rtol·|x|`` within ``config.max_steps``.
    """
    zeros = jnp.zeros(x0.shape, jnp.int32)
    init = (x0, jnp.zeros(x0.shape, bool), zeros, jnp.asarray(0, jnp.int32))

    def cond(state):
        _, done, _, step = state
        return (step < config.max_steps) & ~jnp.all(done)

    def body(state):
        x, done, n, step = state
        x_new = g(x, args)
        active = ~done
        tol = config.atol_umol_mol + config.rtol * jnp.abs(x_new)
        finished = jnp.isfinite(x_new) & (jnp.abs(x_new - x) <= tol)
        return (
            jnp.where(active, x_new, x),
            done | (active & finished),
            n + active.astype(jnp.int32),
            step + 1,
        )

    x, done, n, _ = jax.lax.while_loop(cond, body, init)
    return RootResult(x, done, n)
