"""Where lightfit keeps what it can rebuild: one cache root for every kind of cache.

``$LIGHTFIT_CACHE`` if set, else ``~/.cache/lightfit``. Below it: ``plants/`` (grown plants,
:mod:`lightfit.plant.cache`), ``designs/`` (emulator design renders and fitted emulators,
:func:`lightfit.model.emulator.design_dir`), ``jax/`` (JAX's persistent compilation cache,
:func:`lightfit.precision.use_compilation_cache`) and ``tables/`` (the GGX albedo table,
:func:`lightfit.light.bsdf.ggx_albedo_table`). Deleting any of them is safe: it costs time,
never results.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable naming the cache root.
ENV_CACHE = "LIGHTFIT_CACHE"


def cache_root(cache: str | Path | None = None) -> Path:
    """The cache root: ``cache`` if given, else ``$LIGHTFIT_CACHE``, else ``~/.cache/lightfit``."""
    if cache is not None:
        return Path(cache)
    env = os.environ.get(ENV_CACHE)
    return Path(env) if env else Path.home() / ".cache" / "lightfit"
