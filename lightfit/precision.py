"""lightfit's JAX policy for entry points: float64, and compiled code kept across runs.

JAX defaults to float32; lightfit's tests, experiments and the stored regression reference are
float64, and the model asks for float64 arrays explicitly (which JAX would otherwise truncate
with a warning). Importing lightfit never changes JAX's configuration (a library must not
change its host's global state); the entry points do, by calling :func:`use_float64` before
any computation:

- the ``lightfit`` command line (each command, once it has read its arguments),
- every script in ``experiments/`` and ``benchmarks/``,
- Dask worker processes (:func:`lightfit.distributed.run._worker_setup`).

There is no float32 mode: nothing tests it, and calibration (BFGS) and the photosynthesis
fixed point need float64 to converge to the tolerances they are checked against.

The command line also keeps JAX's compiled programs on disk (:func:`use_compilation_cache`): the
photosynthesis and observation operator compile ~64 small XLA programs, several seconds of every
run that a second run of the same configuration need not repeat.

:func:`sqrt_or_zero` is the one guard for a square root whose argument can be exactly 0 in a
differentiated computation (a standard deviation at night, a discriminant that vanishes);
:func:`power_of_two_scale` the one for a quotient whose numbers can be as small as 1e-154, where its
derivative would square them out of float64's range.
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


def use_compilation_cache(directory=None) -> None:
    """Keep JAX's compiled programs in ``directory`` (default ``<cache root>/jax``,
    :func:`lightfit.cache.cache_root`) and reuse them in later processes. Idempotent.

    JAX's persistent cache stores only programs that took ≥ 1 s to compile by default; each of
    lightfit's takes ~0.1 s, so the thresholds are set to zero (all 64 of the main job's programs,
    ≈ 0.4 MB). A ``JAX_COMPILATION_CACHE_DIR`` set by the user wins. Entries are keyed by JAX on the
    program, the jaxlib version and the machine, so a stale entry is never used; the directory may
    be deleted at any time.

    No size cap, so no lock: JAX locks its entries only with a cap (``jax_compilation_cache_max_size``),
    whose eviction reads every entry's ``-atime`` file and, where one is missing (an entry of a
    cache made without a cap, or of a process killed between its two writes), fails every later
    write with a warning, for good. Uncapped, JAX writes an entry in place, so entries are written
    whole here instead (:func:`_write_entries_whole`): a process killed while writing one
    (``field-run``'s workers are killed outright on Ctrl-C or ``--timeout``) left a cut entry that every
    later run read, warned about ("Error reading persistent compilation cache entry") and compiled
    again, for good, and two workers compiling one program at once read one another's half entry.
    """
    import jax

    from lightfit.cache import cache_root

    if jax.config.jax_compilation_cache_dir is None:  # JAX_COMPILATION_CACHE_DIR sets it
        jax.config.update("jax_compilation_cache_dir", str(directory or cache_root() / "jax"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    _write_entries_whole()


def _write_entries_whole() -> None:
    """Make JAX's uncapped file cache write each entry through :func:`lightfit.files.replaced` (a
    temporary file renamed onto it), and write it even where a file of that name exists. JAX writes
    in place and skips an existing entry: it reaches the write only after a miss or an entry it could
    not read, so an existing file is a cut one (rewritten whole now: the cache heals) or one another
    process has just written (the same program, replaced by a whole copy). A capped cache (its own
    lock and access times) and a folder that is no local path are left to JAX, as is a JAX whose
    cache lacks the names used here."""
    try:
        from jax._src import lru_cache
    except ImportError:
        return
    cls, suffix = getattr(lru_cache, "LRUCache", None), getattr(lru_cache, "_CACHE_SUFFIX", None)
    put = getattr(cls, "put", None)
    if put is None or suffix is None or getattr(put, "_whole", False):
        return

    def put_whole(self, key: str, value: bytes) -> None:
        if getattr(self, "eviction_enabled", True) or not key or "://" in str(self.path):
            return put(self, key, value)
        from pathlib import Path

        from lightfit.files import replaced

        with replaced(Path(str(self.path)) / f"{key}{suffix}") as tmp:
            tmp.write_bytes(value)

    put_whole._whole = True
    cls.put = put_whole


def precision() -> str:
    """Name of the dtype JAX gives a Python float now: ``"float64"`` after :func:`use_float64`."""
    import jax

    return jax.dtypes.canonicalize_dtype(float).name


def sqrt_or_zero(x, xp=None):
    r"""√x where x > 0, 0 where x ≤ 0, with derivative 0 there instead of √'s infinite one; NaN
    stays NaN (a missing or broken input must not read as an exact 0).

    ``d√x/dx = 1/(2√x)`` is infinite at 0, and the chain rule's ``0 · ∞`` makes a gradient NaN
    even where the result does not depend on the input (a standard deviation that is 0 at night
    or for a segment without Monte Carlo error, times a factor being differentiated). The inner
    ``where`` keeps the non-taken branch's √ away from 0 (the "double where": JAX differentiates
    both branches). For a sum of squares, 0 is the subgradient of least norm at the origin.
    ``xp``: the array namespace (default :mod:`jax.numpy`; :mod:`numpy` for plain arrays).
    """
    if xp is None:
        import jax.numpy as xp
    positive = x > 0
    return xp.where(positive, xp.sqrt(xp.where(positive, x, 1.0)), xp.where(x <= 0, 0.0, xp.nan))


def power_of_two_scale(x, xp=None):
    r"""A power of two :math:`k` with :math:`|k x|` in [0.5, 1) where :math:`x` is a normal number
    and :math:`k` and :math:`1/k` are too; 1 elsewhere (0, NaN, infinite, subnormal). Its derivative
    is 0 (it is made of the integer exponent alone).

    Multiplying by :math:`k` is exact, so a formula homogeneous of degree one gives the same numbers
    taken on its inputs times :math:`k` and divided by :math:`k`, and its derivatives stay in range:
    JAX's quotient rule takes ``x·y⁻²``, and ``y⁻²`` overflows for ``|y| < 1e-154`` in float64 (with
    the chain rule's ``0 · ∞``, a NaN) where the derivative itself is of order ``1/y``. A product,
    not a division by ``2^e``: XLA rewrites ``(a/b)/(c/b)`` as a quotient of products, which
    underflowed again. ``xp``: the array namespace (default :mod:`jax.numpy`; :mod:`numpy` for
    plain arrays).
    """
    if xp is None:
        import jax.numpy as xp
    x = xp.asarray(x)
    e = xp.frexp(x)[1]
    e = xp.where(xp.abs(e) <= xp.finfo(x.dtype).maxexp - 2, e, 0)
    return xp.ldexp(xp.ones_like(x), -e)
