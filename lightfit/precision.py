"""lightfit's precision policy: every entry point that computes runs JAX in float64.

JAX defaults to float32; lightfit's tests, experiments and the stored regression reference are
float64, and the model asks for float64 arrays explicitly (which JAX would otherwise truncate
with a warning). Importing lightfit never changes JAX's configuration (a library must not
change its host's global state); the entry points do, by calling :func:`use_float64` before
any computation:

- the ``lightfit`` command line (its app callback),
- every script in ``experiments/`` and ``benchmarks/``,
- Dask worker processes (:func:`lightfit.distributed.run._worker_setup`).

There is no float32 mode: nothing tests it, and calibration (BFGS) and the photosynthesis
fixed point need float64 to converge to the tolerances they are checked against.
"""

from __future__ import annotations

#: The one precision lightfit computes in (name of the JAX default float dtype).
PRECISION = "float64"


def use_float64() -> None:
    """Make float64 JAX's default float dtype in this process. Idempotent.

    Call it before creating JAX arrays: arrays made earlier keep their float32 dtype and
    functions already traced keep their float32 signature.
    """
    import jax

    if not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)


def precision() -> str:
    """Name of the dtype JAX gives a Python float now: ``"float64"`` after :func:`use_float64`."""
    import jax

    return jax.dtypes.canonicalize_dtype(float).name
