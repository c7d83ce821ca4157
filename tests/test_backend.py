"""Backend choice: libLLVM discovery, variant selection, clear errors."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from lightfit.light import backend


def test_finds_libllvm_16_or_newer():
    path = backend.find_libllvm()
    assert path is not None and os.path.exists(path)
    assert backend._llvm_major(path) >= 16


def test_user_llvm_path_wins_and_is_checked(monkeypatch, tmp_path):
    fake = tmp_path / "libLLVM.so.99"
    fake.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(fake))
    monkeypatch.delitem(backend._STATE, "llvm", raising=False)  # as in a fresh process
    assert backend.configure_libllvm() == (str(fake), "user")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "missing.so"))
    monkeypatch.delitem(backend._STATE, "llvm", raising=False)
    with pytest.raises(backend.BackendError, match="does not exist"):
        backend.configure_libllvm()


@pytest.mark.parametrize("what", ["folder", "text file"])
def test_a_user_llvm_path_that_is_no_library_is_a_clear_error(tmp_path, what):
    """DRJIT_LIBLLVM_PATH naming a folder or a file that is no shared library stopped `lightfit info`
    (and every render) with Dr.Jit's ImportError and a traceback; now exit 2 naming the variable."""
    path = tmp_path
    if what == "text file":
        path = tmp_path / "libLLVM.so.99"
        path.write_text("not a library\n")
    env = os.environ | {"DRJIT_LIBLLVM_PATH": str(path), "LIGHTFIT_CACHE": str(tmp_path), "COLUMNS": "400"}
    env.pop(backend.ENV_VARIANT, None)
    cmd = [sys.executable, "-m", "lightfit.cli", "--variant", "llvm_ad_mono", "info"]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr, out.stderr
    err = " ".join(out.stderr.split())
    assert "error: Mitsuba variant 'llvm_ad_mono' could not start" in err, err  # after Dr.Jit's own lines
    assert f"DRJIT_LIBLLVM_PATH='{path}' (you set): point it at a libLLVM.so >= 16" in err, err


def test_the_libllvm_lightfit_found_is_not_reported_as_the_users(monkeypatch):
    """Importing lightfit sets DRJIT_LIBLLVM_PATH to the libLLVM it found; a later call read that
    variable back and `lightfit info` said "(user)" (a CLI review). A fresh process, no variable set."""
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    code = "import lightfit; from lightfit.light import backend; print(backend.configure_libllvm()[1])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "lightfit", out


def test_variant_precedence(monkeypatch):
    monkeypatch.setenv("LIGHTFIT_VARIANT", "llvm_ad_rgb")
    assert backend.choose_variant("scalar_rgb") == ("scalar_rgb", "argument")
    assert backend.choose_variant() == ("llvm_ad_rgb", "env")
    monkeypatch.delenv("LIGHTFIT_VARIANT")
    expected = "cuda_ad_mono" if backend.cuda_usable() else "llvm_ad_mono"
    assert backend.choose_variant() == (expected, "auto")


def test_mitsuba_renders_with_llvm_in_a_fresh_process():
    # A fresh interpreter, so DRJIT_LIBLLVM_PATH is set by lightfit before mitsuba's first import.
    code = (
        "import os; os.environ.pop('DRJIT_LIBLLVM_PATH', None)\n"
        "from lightfit.light import backend\n"
        "mi = backend.mitsuba('llvm_ad_mono')\n"
        "import drjit as dr\n"
        "s = mi.load_dict({'type': 'scene', 'sh': {'type': 'sphere'}})\n"
        "ray = mi.Ray3f(mi.Point3f(0, 0, -5), mi.Vector3f(0, 0, 1))\n"
        "si = s.ray_intersect(ray)\n"
        "print(mi.variant(), os.environ['DRJIT_LIBLLVM_PATH'], float(si.t[0]))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DRJIT_LIBLLVM_PATH", "LIGHTFIT_VARIANT")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    variant, llvm, t = out.stdout.split()
    assert variant == "llvm_ad_mono" and "libLLVM" in llvm
    assert float(t) == pytest.approx(4.0, abs=1e-5)  # unit sphere hit at distance 5 − 1


@pytest.mark.parametrize("user", [None, "true"])
def test_jax_leaves_the_gpu_memory_to_dr_jit_unless_the_user_says(user):
    """Importing lightfit turns off JAX's preallocation of 75 % of a GPU (which a CUDA jaxlib would
    take from Dr.Jit's cuda_ad renders); a value the user set stays. JAX reads it from the
    environment when it creates its client, so a fresh interpreter shows what JAX would see."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_PYTHON_CLIENT_PREALLOCATE"}
    if user is not None:
        env["XLA_PYTHON_CLIENT_PREALLOCATE"] = user
    code = "import os, lightfit; print(os.environ['XLA_PYTHON_CLIENT_PREALLOCATE'])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == (user or "false")


@pytest.mark.parametrize("n", [0, 1, 7323, backend.SUM_BLOCK, 3 * backend.SUM_BLOCK + 5])
def test_sum_float64_is_the_float64_sum_with_the_same_bits_on_any_thread_count(n):
    """The reverse passes' sum (per-hit gradients, summed on the device in blocks): numpy's float64
    sum of the same values to rounding, and bit-identical whatever Dr.Jit's thread count."""
    import drjit as dr

    mi = backend.mitsuba()
    x = np.random.default_rng(n).standard_normal(n).astype(np.float32) * 1e3
    a = mi.Float(x)
    want = float(np.sum(x.astype(np.float64)))
    assert backend.sum_float64(a) == pytest.approx(want, rel=1e-12, abs=1e-9)
    threads = dr.thread_count()
    try:
        got = set()
        for k in (1, 2, 5):
            dr.set_thread_count(k)
            got.add(backend.sum_float64(a))
    finally:
        dr.set_thread_count(threads)
    assert len(got) == 1


def test_unknown_variant_and_missing_cuda_are_clear_errors():
    with pytest.raises(backend.BackendError, match="not in this Mitsuba build"):
        backend.mitsuba("llvm_ad_hyperspectral")
    # In the build but unable to render lightfit's scenes (tracebacks in the leaf BSDF before):
    # refused before anything is set, naming the variants that can.
    for variant in ("scalar_rgb", "llvm_ad_mono_polarized"):
        with pytest.raises(backend.BackendError, match=f"{variant}' cannot run.*llvm_ad_mono"):
            backend.mitsuba(variant)
    if not backend.cuda_usable():
        with pytest.raises(backend.BackendError, match="needs a CUDA device"):
            backend.mitsuba("cuda_ad_mono")


def test_a_bad_variant_names_its_option_and_only_the_variants_that_run_here(monkeypatch):
    """Without CUDA, the list offered cuda_ad_mono, which was then refused, and a misspelt cuda_ad_*
    was told to find a CUDA device instead of that it does not exist; neither said which option."""
    monkeypatch.setattr(backend, "cuda_usable", lambda: False)
    monkeypatch.delenv(backend.ENV_VARIANT, raising=False)
    for variant, why in (("cuda_ad_mnoo", "is not in this Mitsuba build"), ("scalar_rgb", "cannot run")):
        with pytest.raises(backend.BackendError) as e:
            backend.mitsuba(variant)
        msg = str(e.value)
        assert f"--variant: Mitsuba variant '{variant}' {why}" in msg, msg
        offered = msg.split("usable here: ")[1].split(", ")
        assert "llvm_ad_mono" in offered and not [v for v in offered if v.startswith("cuda")], msg
    with pytest.raises(
        backend.BackendError, match=r"^--variant: Mitsuba variant 'cuda_ad_mono' needs a CUDA device.*llvm_ad_mono"
    ):
        backend.mitsuba("cuda_ad_mono")
    monkeypatch.setenv(backend.ENV_VARIANT, "llvm_ad_mnoo")
    monkeypatch.delitem(backend._STATE, "mi", raising=False)  # a backend set up by an earlier test is kept
    with pytest.raises(
        backend.BackendError, match=r"^LIGHTFIT_VARIANT: Mitsuba variant 'llvm_ad_mnoo' is not in this Mitsuba build"
    ):
        backend.mitsuba()


def test_missing_llvm_message(monkeypatch):
    monkeypatch.setitem(backend._STATE, "llvm", (None, None))
    monkeypatch.delitem(backend._STATE, "mi", raising=False)
    with pytest.raises(backend.BackendError, match="karellen-llvm-core"):
        backend.mitsuba("llvm_ad_rgb")


def test_libllvm_major_is_read_from_each_naming():
    assert backend._llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-17.so") == 17
    assert backend._llvm_major("/env/lib/libLLVM.so.18.1") == 18
    assert backend._llvm_major("/usr/lib/llvm-15/lib/libLLVM-15.so.1") == 15
    assert backend._llvm_major("libLLVM.so") is None


def test_find_libllvm_takes_16_and_newer_newest_major_first(monkeypatch):
    """MIN_LLVM_MAJOR = 16 is allowed (15 is not); the newest major wins over a longer file name; within a
    major the fully versioned file wins. Candidates stand in for the folders' contents."""

    def pick(names):
        monkeypatch.setattr(backend.glob, "glob", lambda pattern: list(names))
        monkeypatch.setattr(backend.ctypes.util, "find_library", lambda name: None)
        return backend.find_libllvm()

    assert pick(["/l/libLLVM-15.so", "/l/libLLVM-14.so.1"]) is None
    assert pick(["/l/libLLVM-15.so", "/l/libLLVM-16.so"]) == "/l/libLLVM-16.so"
    assert pick(["/l/libLLVM.so.16.0.6", "/l/libLLVM-17.so"]) == "/l/libLLVM-17.so"
    assert pick(["/l/libLLVM-18.so", "/l/libLLVM.so.18.1"]) == "/l/libLLVM.so.18.1"


# A leaf spanning the periodic cell: every projected ray lands on it, so its direct sun is sin β per
# unit DNI exactly on its upper side (as in test_light_projection.py); two bounces add BSDF sampling
# and the soil's light on its underside.
_LEAF_RENDER = """
import json, math, sys
sys.path.insert(0, {tests!r})
from test_periodic import square
from lightfit.light import backend
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant.periodic import PeriodicCell
cell = PeriodicCell(0.2, 0.3, row_direction_deg=70.0)
mesh = square([0.0, 0.0, 0.4], [0, 0, 1], 1.0, 1)
mesh.vertices[:, :2] = cell.corners_xy
fs = FieldScene(mesh, Optics.preset("prospect"), cell=cell)
fs.set_sun(35.0, 120.0)
est = SegmentEstimator(fs, [1], samples=8, bounces=2, seed=3, direct="projection", direct_rays_per_m2=2e6)
r = est.render()
names = ("incident_sun", "incident_sky", "absorbed_sun", "absorbed_sky")
print(json.dumps({{"info": backend.info().llvm_target, "drjit": backend.llvm_target(),
                  "front_sun": float(r.front("incident_sun")[0]), "values": [float(getattr(r, n)[0]) for n in names]}}))
"""


def _leaf_render(target: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != backend.ENV_LLVM_TARGET}
    if target is not None:
        env[backend.ENV_LLVM_TARGET] = target
    code = _LEAF_RENDER.format(tests=os.path.dirname(__file__))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.splitlines()[-1])


def test_llvm_target_env_compiles_every_kernel_for_the_named_cpu_and_renders_the_same_light():
    """LIGHTFIT_LLVM_TARGET=avx2 (the target of an AVX2 machine, which this one may emulate: it has AVX2)
    sets drjit-core's CPU, features and 8 lanes, says so in BackendInfo, and renders the analytic direct
    sun and, to float32 rounding, the light of this CPU's own kernels (not bitwise: other code)."""
    native = _leaf_render(None)
    if "+avx2" not in native["drjit"][1].split(","):
        pytest.skip("this CPU lacks AVX2")
    avx2 = _leaf_render("avx2")
    cpu, features, lanes = backend.LLVM_TARGETS["avx2"]
    assert avx2["drjit"] == [cpu, features, lanes]
    assert avx2["info"] == f"{cpu}, 8 lanes (LIGHTFIT_LLVM_TARGET=avx2)"
    assert native["info"] == f"{native['drjit'][0]}, {native['drjit'][2]} lanes (auto)"
    assert avx2["front_sun"] == pytest.approx(math.sin(math.radians(35.0)), rel=1e-6)  # the upper side
    assert avx2["values"][0] > avx2["front_sun"]  # the soil's light reaches the underside
    np.testing.assert_allclose(avx2["values"], native["values"], rtol=2e-6)


def test_llvm_target_refuses_unknown_names_and_features_this_cpu_lacks(monkeypatch):
    """Refused before anything is set: an unknown name lists the known ones; a target needing a feature
    the CPU lacks (its kernels would stop on an illegal instruction) names the feature."""
    monkeypatch.setitem(backend._STATE, "llvm_target", "restored after the test, present or not")
    monkeypatch.delitem(backend._STATE, "llvm_target")  # as in a fresh process
    monkeypatch.setattr(backend, "set_llvm_target", lambda *a: pytest.fail("a target was set"))
    monkeypatch.setenv(backend.ENV_LLVM_TARGET, "sse9")
    with pytest.raises(backend.BackendError, match=r"LIGHTFIT_LLVM_TARGET='sse9' .*avx2, avx512"):
        backend.configure_llvm_target()
    cpu, features, _ = backend.LLVM_TARGETS["avx2"]
    monkeypatch.setattr(backend, "llvm_target", lambda: ("haswell", features, 8))  # an AVX2-only CPU
    monkeypatch.setenv(backend.ENV_LLVM_TARGET, " AVX512 ")
    with pytest.raises(backend.BackendError, match=r"=avx512 needs .*\(\+avx512f, \+avx512bw, .*avx2"):
        backend.configure_llvm_target()
    assert "llvm_target" not in backend._STATE

    def no_symbol():  # a Dr.Jit whose core does not export the calls (ctypes' AttributeError)
        raise AttributeError("undefined symbol: _Z24jit_llvm_target_featuresv")

    monkeypatch.setattr(backend, "llvm_target", no_symbol)
    with pytest.raises(backend.BackendError, match="does not let lightfit set its CPU target; unset"):
        backend.configure_llvm_target()
    monkeypatch.delenv(backend.ENV_LLVM_TARGET)  # unset: renders on, saying it cannot tell
    assert backend.configure_llvm_target() == "unknown: this Dr.Jit does not say"
    del backend._STATE["llvm_target"]
    monkeypatch.setattr(backend, "llvm_target", lambda: ("haswell", features, 8))
    monkeypatch.setattr(backend, "set_llvm_target", lambda *a: no_symbol())  # getters but no setter
    monkeypatch.setenv(backend.ENV_LLVM_TARGET, "avx2")
    with pytest.raises(backend.BackendError, match="does not let lightfit set its CPU target; unset"):
        backend.configure_llvm_target()
