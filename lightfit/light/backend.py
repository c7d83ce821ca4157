"""The one place that decides how Mitsuba runs: libLLVM discovery and variant choice.

Mitsuba's CPU (``llvm_ad_*``) variants JIT-compile through libLLVM >= 16, which
Debian/Ubuntu do not ship by default (their libLLVM 14/15 crash with "Cannot select:
fminimum"). lightfit depends on the ``karellen-llvm-core`` wheel, which installs
``lib/libLLVM.so.<major>.<minor>`` under the environment prefix, and points Dr.Jit at it
through ``DRJIT_LIBLLVM_PATH`` *before* the first ``import mitsuba`` — unless the user
already set that variable, which always wins.

Variant choice: ``cuda_ad_<mode>`` when a CUDA device is usable, else ``llvm_ad_<mode>``.
Override with the environment variable ``LIGHTFIT_VARIANT`` (e.g. ``llvm_ad_mono``) or the
CLI flag ``lightfit --variant``. Every other module gets Mitsuba through :func:`mitsuba`.

CPU kernels: Dr.Jit compiles them for the CPU it runs on (16 lanes with AVX-512, 8 with AVX2),
and different code rounds differently in float32's last digits. ``LIGHTFIT_LLVM_TARGET`` names one
of :data:`LLVM_TARGETS` for every machine of a heterogeneous cluster, so that their renders are the
same to the bit (docs/light.md, "CPU targets").
"""

from __future__ import annotations

import ctypes.util
import glob
import importlib
import importlib.metadata
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import numpy as np

#: Colour mode of the variant: PAR is one band, so monochrome is all lightfit needs.
DEFAULT_MODE = "mono"
MIN_LLVM_MAJOR = 16
ENV_VARIANT = "LIGHTFIT_VARIANT"
ENV_LLVM = "DRJIT_LIBLLVM_PATH"
ENV_LLVM_TARGET = "LIGHTFIT_LLVM_TARGET"

_X86_64_V3 = (
    "+64bit,+sse,+sse2,+sse3,+ssse3,+sse4.1,+sse4.2,+popcnt,+cx16,+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,+movbe"
)
#: Named CPU targets for ``LIGHTFIT_LLVM_TARGET``: (LLVM CPU, LLVM features, lanes per packet). The
#: x86-64 micro-architecture levels v3 (AVX2, FMA, BMI2: Intel since Haswell, AMD since Zen) and v4 (AVX-512).
LLVM_TARGETS: dict[str, tuple[str, str, int]] = {
    "avx2": ("x86-64-v3", _X86_64_V3, 8),
    "avx512": ("x86-64-v4", _X86_64_V3 + ",+avx512f,+avx512bw,+avx512cd,+avx512dq,+avx512vl", 16),
}


class BackendError(RuntimeError):
    """Mitsuba cannot run here; the message names what is missing and how to get it."""


@dataclass(frozen=True)
class BackendInfo:
    """What :func:`mitsuba` configured.

    Attributes:
        variant: the Mitsuba variant in use, e.g. ``llvm_ad_mono``.
        libllvm: path of the libLLVM Dr.Jit loads (``None`` for CUDA-only use).
        libllvm_source: ``"user"`` if ``DRJIT_LIBLLVM_PATH`` was set before lightfit,
            ``"lightfit"`` if lightfit found it, ``None`` if not found.
        variant_source: ``"argument"``, ``"env"`` or ``"auto"``.
        llvm_target: what Dr.Jit compiles CPU kernels for, e.g. ``znver5, 16 lanes (auto)`` or
            ``x86-64-v3, 8 lanes (LIGHTFIT_LLVM_TARGET=avx2)``; ``None`` for CUDA variants.
    """

    variant: str
    libllvm: str | None
    libllvm_source: str | None
    variant_source: str
    llvm_target: str | None = None


_STATE: dict[str, object] = {}


def _llvm_major(path: str) -> int | None:
    m = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", Path(path).name)
    return int(m.group(1)) if m else None


def find_libllvm() -> str | None:
    """Return the path of a libLLVM >= 16 shared library, or ``None``.

    Search order: the environment prefix (``karellen-llvm-core`` puts it in
    ``<prefix>/lib``), then the system linker path (e.g. Debian's ``libllvm19``).
    The highest major version wins.
    """
    candidates: list[str] = []
    for prefix in {sys.prefix, sys.base_prefix}:
        candidates += glob.glob(os.path.join(prefix, "lib", "libLLVM*.so*"))
    for d in ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib", "/usr/local/lib"):
        candidates += glob.glob(os.path.join(d, "libLLVM*.so*"))
        candidates += glob.glob(os.path.join(d, "llvm-*", "lib", "libLLVM*.so*"))
    found = ctypes.util.find_library("LLVM")
    if found:
        candidates.append(found)
    good = [(major, c) for c in candidates if (major := _llvm_major(c)) and major >= MIN_LLVM_MAJOR]
    if not good:
        return None
    # Prefer the fully versioned file (libLLVM.so.23.1) of the newest major.
    good.sort(key=lambda mc: (mc[0], len(Path(mc[1]).name)), reverse=True)
    return good[0][1]


def configure_libllvm() -> tuple[str | None, str | None]:
    """Set ``DRJIT_LIBLLVM_PATH`` unless the user did; return (path, source).

    Dr.Jit reads the variable when it is imported: if ``drjit`` was imported before lightfit
    configured it, a warning says so (the system's libLLVM may then be too old). The first answer
    is kept: a second call would take the variable lightfit set for the user's own.
    """
    if "llvm" in _STATE:
        return _STATE["llvm"]  # type: ignore[return-value]
    user = os.environ.get(ENV_LLVM)
    if "drjit" in sys.modules and not user:
        import warnings

        warnings.warn(
            "drjit was imported before lightfit could set DRJIT_LIBLLVM_PATH; import lightfit first "
            "(or set DRJIT_LIBLLVM_PATH yourself) so that Dr.Jit uses libLLVM >= 16",
            RuntimeWarning,
            stacklevel=2,
        )
    if user:
        if not Path(user).exists():
            raise BackendError(
                f"{ENV_LLVM}={user!r} does not exist; unset it or point it at libLLVM >= {MIN_LLVM_MAJOR}"
            )
        _STATE["llvm"] = (user, "user")
    else:
        path = find_libllvm()
        if path is not None:
            os.environ[ENV_LLVM] = path
        _STATE["llvm"] = (path, None if path is None else "lightfit")
    return _STATE["llvm"]  # type: ignore[return-value]


def configure_jax_memory() -> None:
    """Keep JAX from preallocating a GPU's memory, unless the user set it
    (``XLA_PYTHON_CLIENT_PREALLOCATE``).

    With a CUDA jaxlib installed, JAX takes 75 % of a GPU's memory at its first computation
    there, and Dr.Jit's renders in ``cuda_ad_*`` would then run out of what is left; lightfit's
    JAX work (photosynthesis, inference) needs little. JAX reads the variable when it creates its
    GPU client, so this holds where lightfit is imported before JAX first computes on a GPU (a
    notebook that does that first keeps JAX's default); it applies to the whole process.
    """
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")


def cuda_usable() -> bool:
    """True when the CUDA driver library loads and reports at least one device."""
    name = ctypes.util.find_library("cuda")
    if not name:
        return False
    try:
        lib = ctypes.CDLL(name)
        if lib.cuInit(0) != 0:
            return False
        count = ctypes.c_int(0)
        return lib.cuDeviceGetCount(ctypes.byref(count)) == 0 and count.value > 0
    except OSError:
        return False


def choose_variant(requested: str | None = None, mode: str = DEFAULT_MODE) -> tuple[str, str]:
    """Pick the Mitsuba variant: explicit argument > ``LIGHTFIT_VARIANT`` > auto.

    Returns (variant, source). Auto is ``cuda_ad_<mode>`` if :func:`cuda_usable`, else
    ``llvm_ad_<mode>``.
    """
    if requested:
        return requested, "argument"
    env = os.environ.get(ENV_VARIANT)
    if env:
        return env, "env"
    return (f"cuda_ad_{mode}" if cuda_usable() else f"llvm_ad_{mode}"), "auto"


def mitsuba(variant: str | None = None) -> ModuleType:
    """Import Mitsuba with libLLVM configured and the variant set; return the module.

    Calling it again with no argument returns the already configured module; calling it
    with a different variant switches variant.

    Raises:
        BackendError: libLLVM >= 16 missing for an ``llvm_*`` variant, the variant is not
            compiled into this Mitsuba build, CUDA was requested without a device, or Dr.Jit
            cannot start the variant (e.g. ``DRJIT_LIBLLVM_PATH`` names a file that is no libLLVM).
    """
    if "mi" in _STATE and variant in (None, _STATE["info"].variant):  # type: ignore[union-attr]
        return _STATE["mi"]
    libllvm, llvm_source = configure_libllvm()
    chosen, source = choose_variant(variant)
    if chosen.startswith("llvm") and libllvm is None:
        raise BackendError(
            f"Mitsuba variant {chosen!r} needs libLLVM >= {MIN_LLVM_MAJOR}, and none was found in "
            f"{sys.prefix}/lib or the system library path. Install the 'karellen-llvm-core' wheel "
            f"(a lightfit dependency: `python3 tasks.py setup`) or set {ENV_LLVM} to a libLLVM.so."
        )
    mi = importlib.import_module("mitsuba")
    # The option that asked for it (the command line passes --variant as the argument).
    asked = ENV_VARIANT if source == "env" else "--variant"
    cuda = cuda_usable()
    usable = [v for v in mi.variants() if v.startswith(("llvm_ad_", "cuda_ad_")) and "polarized" not in v]
    here = [v for v in usable if (cuda if v.startswith("cuda") else libllvm is not None)]
    if chosen not in usable:
        # The estimator runs vectorised Dr.Jit kernels and differentiates them, with unpolarised
        # spectra: scalar_*, non-AD and *_polarized variants are in the build but cannot render
        # lightfit's scenes (a traceback deep in the leaf BSDF before).
        why = "is not in this Mitsuba build" if chosen not in mi.variants() else "cannot run lightfit's renders"
        raise BackendError(
            f"{asked}: Mitsuba variant {chosen!r} {why}; lightfit needs a vectorised differentiable one "
            f"(llvm_ad_* or cuda_ad_*, not polarised), usable here: {', '.join(here)}"
        )
    if chosen.startswith("cuda") and not cuda:
        raise BackendError(
            f"{asked}: Mitsuba variant {chosen!r} needs a CUDA device and driver; none is usable here. "
            f"Use an llvm_ad_* variant (unset {ENV_VARIANT} or drop --variant), usable here: {', '.join(here)}"
        )
    try:
        mi.set_variant(chosen)
    except ImportError as e:  # Dr.Jit could not load its backend, e.g. DRJIT_LIBLLVM_PATH is no libLLVM
        hint = ""
        if chosen.startswith("llvm"):
            who = "you set" if llvm_source == "user" else "lightfit found"
            hint = f" {ENV_LLVM}={libllvm!r} ({who}): point it at a libLLVM.so >= {MIN_LLVM_MAJOR}, or unset it."
        raise BackendError(f"Mitsuba variant {chosen!r} could not start: {e}{hint}") from e
    target = configure_llvm_target() if chosen.startswith("llvm") else None
    _STATE["mi"] = mi
    _STATE["info"] = BackendInfo(chosen, libllvm, llvm_source, source, target)
    return mi


def _drjit_core():
    """Dr.Jit's core library, for the LLVM target calls its Python API does not expose."""
    import drjit as dr

    return ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))


def llvm_target() -> tuple[str, str, int]:
    """(LLVM CPU, LLVM features, lanes) that Dr.Jit compiles CPU kernels for now."""
    lib, text = _drjit_core(), ctypes.CFUNCTYPE(ctypes.c_char_p)
    cpu = text(("_Z19jit_llvm_target_cpuv", lib))().decode()
    features = text(("_Z24jit_llvm_target_featuresv", lib))().decode()
    return cpu, features, ctypes.CFUNCTYPE(ctypes.c_uint32)(("_Z21jit_llvm_vector_widthv", lib))()


def set_llvm_target(cpu: str, features: str, lanes: int) -> None:
    """Compile every later CPU kernel for ``cpu`` with ``features`` (LLVM's names, comma-separated
    ``+feature``) and ``lanes`` per packet. Call it after the LLVM variant is set and before any
    kernel compiles (:func:`mitsuba` does, for ``LIGHTFIT_LLVM_TARGET``); the benchmarks call it to
    time other packet widths."""
    set_target = ctypes.CFUNCTYPE(None, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32)
    set_target(("_Z19jit_llvm_set_targetPKcS0_j", _drjit_core()))(cpu.encode(), features.encode(), int(lanes))


def _set_named_target(name: str) -> None:
    """Compile later kernels for :data:`LLVM_TARGETS` ``[name]``, or :class:`BackendError` before
    anything is set: an unknown name, a feature this CPU lacks, a Dr.Jit without the calls."""
    if name not in LLVM_TARGETS:
        raise BackendError(
            f"{ENV_LLVM_TARGET}={os.environ[ENV_LLVM_TARGET]!r} is not a CPU target lightfit knows; "
            f"expected one of {', '.join(LLVM_TARGETS)} (or unset, for this CPU's own)"
        )
    cpu, features, lanes = LLVM_TARGETS[name]
    try:
        here = set(llvm_target()[1].split(","))
        if missing := [f for f in features.split(",") if f not in here]:
            raise BackendError(
                f"{ENV_LLVM_TARGET}={name} needs CPU features this machine lacks ({', '.join(missing)}); "
                f"use a target all your machines have, e.g. {ENV_LLVM_TARGET}=avx2, or unset it"
            )
        set_llvm_target(cpu, features, lanes)
    except (OSError, AttributeError):  # drjit-core without the library calls (ctypes' errors)
        raise BackendError(f"this Dr.Jit does not let lightfit set its CPU target; unset {ENV_LLVM_TARGET}") from None


def configure_llvm_target() -> str:
    """Apply ``LIGHTFIT_LLVM_TARGET`` (once per process: the first LLVM variant's kernels fix it) and
    describe the target in force, for :class:`BackendInfo`.

    Raises:
        BackendError: the name is not in :data:`LLVM_TARGETS`, or the CPU here lacks a feature the
            target needs (its kernels would stop on an illegal instruction).
    """
    if "llvm_target" not in _STATE:
        name = os.environ.get(ENV_LLVM_TARGET, "").strip().lower()
        if name:
            _set_named_target(name)
        source = f"{ENV_LLVM_TARGET}={name}" if name else "auto"
        try:
            cpu, _, lanes = llvm_target()
            _STATE["llvm_target"] = f"{cpu}, {lanes} lanes ({source})"
        except (OSError, AttributeError):  # a Dr.Jit that does not export the calls: say so, render on
            _STATE["llvm_target"] = "unknown: this Dr.Jit does not say"
    return _STATE["llvm_target"]  # type: ignore[return-value]


def package_versions(*packages: str) -> dict[str, str | None]:
    """Installed version of each distribution in ``packages`` (``None`` if not installed as one)."""
    out = {}
    for pkg in packages:
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def variant_in_use() -> str | None:
    """The Mitsuba variant this process renders with, or ``None`` where it has not loaded Mitsuba
    (light injected or read from a file): for results' provenance, without importing Mitsuba."""
    return _STATE["info"].variant if "info" in _STATE else None  # type: ignore[union-attr]


def llvm_target_in_use() -> str | None:
    """The CPU target of this process's renders (:attr:`BackendInfo.llvm_target`), or ``None`` where
    it has not loaded Mitsuba or renders with CUDA: for results' provenance."""
    return _STATE["info"].llvm_target if "info" in _STATE else None  # type: ignore[union-attr]


def thread_count() -> int | None:
    """Dr.Jit's CPU thread pool size in this process (its LLVM kernels run on it), or ``None`` where
    the variant in use is a CUDA one. Dr.Jit's default is one thread per core this process may run
    on (its CPU affinity); no environment variable sets it: ``drjit.set_thread_count(n)`` does
    (render-dataset's ``--threads``; field-run's ``--threads-per-worker``, through
    ``LIGHTFIT_WORKER_THREADS``, in each worker)."""
    if "info" in _STATE and not _STATE["info"].variant.startswith("llvm"):  # type: ignore[union-attr]
        return None
    import drjit as dr

    return int(dr.thread_count())


def info() -> BackendInfo:
    """Configure (if needed) and describe the backend in use."""
    mitsuba()
    return _STATE["info"]  # type: ignore[return-value]


def owned(a, T):
    """A Dr.Jit-owned copy, of Dr.Jit type ``T`` (e.g. ``mi.Float``, ``mi.UInt32``, ``mi.Float64``),
    of a numpy vector, evaluated.

    Dr.Jit may wrap numpy memory instead of copying it, and bakes that memory's alignment into the
    kernels that read it, so kernels reading wrapped arrays are compiled anew whenever the
    alignment differs; kernels reading owned copies are reused (and cached on disk).
    """
    import drjit as dr

    V = dr.VarType
    dtype = {V.Float32: np.float32, V.Float64: np.float64, V.UInt32: np.uint32, V.Bool: np.bool_}[dr.type_v(T)]
    src = T(np.ascontiguousarray(a, dtype=dtype))
    out = dr.empty(T, len(a))
    dr.scatter(out, src, dr.arange(dr.uint32_array_t(T), len(a)))
    dr.eval(out)
    return out


#: Elements per partial sum of :func:`sum_float64` (≈ 1 000 partials for 10⁷ elements).
SUM_BLOCK = 16384


def sum_float64(x) -> float:
    """Σ x, a Dr.Jit array of the current variant, in float64: partial sums over blocks of
    :data:`SUM_BLOCK` on the device, then the partials on the host. Evaluated block reductions
    (``mode="evaluated"``: no atomics, which Dr.Jit would otherwise use for arrays over 1 GiB)
    give the same bits whatever the number of threads (tests/test_backend.py), and only the
    partials are copied: a reverse pass's per-hit gradients (10⁷ floats and more) used to be
    copied whole and summed by numpy, 12× the time of the sum on a GPU (docs/benchmarks.md, "GPU").
    """
    import drjit as dr

    n = dr.width(x)
    if n == 0:
        return 0.0
    partial = dr.block_sum(dr.float64_array_t(type(x))(x), min(SUM_BLOCK, n), mode="evaluated")
    return float(np.sum(np.asarray(partial, dtype=np.float64)))
