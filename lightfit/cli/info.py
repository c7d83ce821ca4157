"""``lightfit info``: versions, the Mitsuba variant in use, the libLLVM path and the CPU target."""

from __future__ import annotations

import os
import sys

from rich.table import Table

from lightfit.cli.common import console

_PACKAGES = (
    "lightfit",
    "jax",
    "jaxlib",
    "drjit",
    "mitsuba",
    "optimistix",
    "jaxopt",
    "emcee",
    "cplantbox",
    "pvlib",
    "numpy",
    "pandas",
    "xarray",
    "trimesh",
)


def info() -> None:
    """Print versions, the Mitsuba variant in use, the libLLVM path, the CPU target, Dr.Jit's CPU threads
    and the JAX precision."""
    from lightfit.light import backend
    from lightfit.precision import precision

    t = Table(title="lightfit environment", show_header=False)
    t.add_row("python", sys.version.split()[0])
    for pkg, version in backend.package_versions(*_PACKAGES).items():
        t.add_row(pkg, version or "[red]not installed[/]")
    t.add_row("JAX precision", precision())
    try:
        b = backend.info()  # the variant of --variant (applied by the app callback), LIGHTFIT_VARIANT or auto
    except backend.BackendError:
        console.print(t)  # what is known so far, then the error handler reports the backend problem
        raise
    t.add_row("mitsuba variant", f"{b.variant} ({b.variant_source})")
    t.add_row("libLLVM", f"{b.libllvm} ({b.libllvm_source})")
    t.add_row("LLVM target", b.llvm_target or "none (CUDA)")
    threads = backend.thread_count()
    if threads is not None:  # how many threads render, and how to change it: Dr.Jit reads no variable
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        t.add_row(
            "Dr.Jit CPU threads",
            f"{threads} ({cores} cores available to this process; set with drjit.set_thread_count(n) in Python, "
            "--threads on render-dataset, --threads-per-worker on field-run's embedded cluster; "
            "no environment variable sets it)",
        )
    t.add_row("CUDA usable", str(backend.cuda_usable()))
    console.print(t)
