"""The precision policy: one call makes JAX compute in float64, and every entry point makes it."""

import ast
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Scripts that never import lightfit or JAX: the LESS runner runs in LESS's own environment
#: (benchmarks/bench_less.py calls it with that interpreter).
FOREIGN = {"less_runner.py"}
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
