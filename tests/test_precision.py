"""The precision policy: one call makes JAX compute in float64, and every entry point makes it."""

import ast
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Scripts that never import lightfit or JAX: the LESS runner runs in LESS's own environment
#: (benchmarks/bench_less.py calls it with that interpreter); bench_variance_compare.py only runs
#: bench_variance.py (which applies the policy) in subprocesses on two source trees; provenance.py is
#: the scripts' record of commit, cores and load, imported by them after they apply it.
FOREIGN = {"less_runner.py", "bench_variance_compare.py", "provenance.py"}
SCRIPTS = [
    p
    for p in sorted((ROOT / "experiments").glob("*.py")) + sorted((ROOT / "benchmarks").glob("*.py"))
    if p.name not in FOREIGN
]


def test_foreign_scripts_do_not_import_lightfit():
    """The exemption above holds only while those scripts stay outside lightfit's environment."""
    for name in FOREIGN:
        text = (ROOT / "benchmarks" / name).read_text(encoding="utf-8")
        assert "import lightfit" not in text and "from lightfit" not in text and "import jax" not in text, name


def test_use_float64_is_idempotent_in_a_fresh_process():
    """The test suite enables x64 itself, so the policy is checked in a fresh interpreter."""
    code = textwrap.dedent(
        """
        import jax.numpy as jnp
        from lightfit.precision import precision, use_float64
        before = precision()
        use_float64()
        use_float64()
        print(before, precision(), jnp.asarray(0.1).dtype, jnp.asarray(0.1, jnp.float64).dtype)
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["float32", "float64", "float64", "float64"]
    assert "warning" not in p.stderr.lower(), p.stderr


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_script_applies_the_policy_at_module_level(script):
    """Each experiment and benchmark calls ``use_float64()`` at its top level (not only inside main())."""
    tree = ast.parse(script.read_text(encoding="utf-8"))
    calls = [
        node
        for node in tree.body
        if isinstance(node, ast.Expr)
        and isinstance(node.value, ast.Call)
        and getattr(node.value.func, "id", None) == "use_float64"
    ]
    assert calls, f"{script.name}: add `from lightfit.precision import use_float64` and `use_float64()` at the top"


def test_compilation_cache_keeps_programs_for_the_next_process(tmp_path):
    """A second process finds the first one's compiled program on disk (JAX reports a cache hit)
    instead of compiling it again; a ``JAX_COMPILATION_CACHE_DIR`` the user set is left alone."""
    code = textwrap.dedent(
        """
        import logging, sys
        import jax, jax.numpy as jnp
        from lightfit.precision import use_compilation_cache
        hits = []
        class H(logging.Handler):
            def emit(self, r):
                hits.append(r.getMessage())
        logging.getLogger("jax._src.compilation_cache").addHandler(H())
        logging.getLogger("jax._src.compilation_cache").setLevel(logging.DEBUG)
        logging.getLogger("jax._src.compiler").addHandler(H())
        logging.getLogger("jax._src.compiler").setLevel(logging.DEBUG)
        use_compilation_cache()
        use_compilation_cache()
        print(jax.config.jax_compilation_cache_dir)
        print(float(jax.jit(lambda x: jnp.sin(x) * 3.0 + x**2)(0.5)))
        print(any("cache hit" in m.lower() for m in hits))
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["LIGHTFIT_CACHE"] = str(tmp_path / "root")
    runs = [
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout.split()
        for _ in range(2)
    ]
    assert runs[0][0] == str(tmp_path / "root" / "jax")
    assert runs[0][1] == runs[1][1]
    assert (runs[0][2], runs[1][2]) == ("False", "True")
    mine = str(tmp_path / "mine")
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**env, "JAX_COMPILATION_CACHE_DIR": mine}
    )
    assert out.stdout.split()[0] == mine and any((tmp_path / "mine").iterdir())


def test_compilation_cache_takes_the_folder_given_and_keeps_every_program(tmp_path):
    """A folder passed in wins over the cache root, and both of JAX's thresholds (compile time, entry
    size) are zero so that lightfit's small programs are kept (a fresh process: the setting is global)."""
    code = textwrap.dedent(
        f"""
        import jax
        from lightfit.precision import use_compilation_cache
        use_compilation_cache({str(tmp_path / "given")!r})
        print(jax.config.jax_compilation_cache_dir)
        c = jax.config
        print(c.jax_persistent_cache_min_compile_time_secs, c.jax_persistent_cache_min_entry_size_bytes)
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["LIGHTFIT_CACHE"] = str(tmp_path / "root")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    lines = out.stdout.splitlines()
    assert lines[0] == str(tmp_path / "given")
    assert [float(v) for v in lines[1].split()] == [0.0, 0.0]


def test_sqrt_or_zero_has_the_roots_value_and_a_finite_slope_at_zero():
    """√x for x > 0 with its derivative 1/(2√x); 0 and a zero derivative at x ≤ 0 (where √'s is
    infinite and 0·∞ made gradients NaN); NaN in, NaN out (a review: a NaN SE read as an SD of 0);
    the same values from numpy."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from lightfit.precision import sqrt_or_zero

    x = np.array([0.0, 1e-300, 0.25, 4.0, -1.0, np.nan])
    np.testing.assert_array_equal(sqrt_or_zero(x, np), [0.0, 1e-150, 0.5, 2.0, 0.0, np.nan])  # NaN stays NaN
    np.testing.assert_array_equal(np.asarray(sqrt_or_zero(jnp.asarray(x))), sqrt_or_zero(x, np))
    slope = np.asarray(jax.vmap(jax.grad(sqrt_or_zero))(jnp.asarray(x)))
    np.testing.assert_allclose(slope[:5], [0.0, 0.5e150, 1.0, 0.25, 0.0], rtol=1e-12)
    # a sum of squares through the origin: the norm's slope along a ray, 0 at the origin
    assert float(jax.grad(lambda t: sqrt_or_zero((3 * t) ** 2 + (4 * t) ** 2))(0.0)) == 0.0
    assert float(jax.grad(lambda t: sqrt_or_zero((3 * t) ** 2 + (4 * t) ** 2))(2.0)) == 5.0


def test_a_cut_compilation_cache_entry_is_rewritten_whole_by_the_next_run(tmp_path):
    """A process killed while JAX wrote an entry leaves it cut. JAX reads it, warns and compiles
    again, but never writes an existing entry: every later run warned, for good. The run after the
    cut one now rewrites it whole (through a temporary file), and the run after that reads it back."""
    code = textwrap.dedent(
        """
        import warnings
        import jax, jax.numpy as jnp
        from lightfit.precision import use_compilation_cache, use_float64
        use_float64()
        use_compilation_cache()
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            print(float(jax.jit(lambda x: jnp.cos(x) * 2.0 + x**3)(0.5)))
        print(sum("persistent compilation cache" in str(x.message) for x in w))
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["LIGHTFIT_CACHE"] = str(tmp_path)

    def run():
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
        value, warned = out.stdout.split()
        return float(value), int(warned)

    expected = math.cos(0.5) * 2.0 + 0.5**3
    assert run() == (pytest.approx(expected, rel=1e-15), 0)
    (entry,) = (tmp_path / "jax").glob("*-cache")
    whole = entry.read_bytes()
    entry.write_bytes(whole[: len(whole) // 2])  # a writer killed half-way
    assert run() == (pytest.approx(expected, rel=1e-15), 1)  # read cut: said once, compiled, rewritten
    assert entry.read_bytes() == whole
    assert run() == (pytest.approx(expected, rel=1e-15), 0)
    assert [p.name for p in (tmp_path / "jax").iterdir()] == [entry.name]  # no temporary file left
