"""lightfit: differentiable light and photosynthesis for wheat canopies.

Data flows one way: ``weather`` -> ``plant`` -> ``light`` -> ``photosynthesis`` -> ``model`` ->
``inference``; ``replication`` (the 20 April 2016 main job), ``distributed``, ``dataset`` and ``cli``
use them and nothing below imports them (docs/architecture.md).
"""

__version__ = "0.1.0"

# First, in a worker process of lightfit's own Dask cluster: its parent handles Ctrl-C.
from lightfit.killpoint import ignore_interrupt_in_workers as _ignore_interrupt_in_workers  # noqa: E402

_ignore_interrupt_in_workers()

# Dr.Jit reads DRJIT_LIBLLVM_PATH when it is first imported, so point it at libLLVM >= 16 as
# early as possible: importing lightfit before drjit/mitsuba is enough. JAX reads
# XLA_PYTHON_CLIENT_PREALLOCATE when it first uses a GPU: set before then too.
from lightfit.light.backend import configure_jax_memory as _configure_jax_memory  # noqa: E402
from lightfit.light.backend import configure_libllvm as _configure_libllvm  # noqa: E402

_configure_jax_memory()

try:
    _configure_libllvm()
except Exception:  # noqa: BLE001 - reported with a clear message when Mitsuba is first used
    pass
