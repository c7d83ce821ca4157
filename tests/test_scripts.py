"""The experiment and benchmark scripts still fit the library they call.

The scripts under experiments/ and benchmarks/ are not run in CI (minutes to hours each), so a
renamed or removed library function would be found only by the next person who runs one (it
happened: docs/model.md records a check script that had stopped working). This test reads every
script's syntax tree and checks each name it takes from lightfit or from a sibling script —
``from lightfit.x import f`` and ``from bench_light import g`` anywhere in the file, function
bodies included, and ``M.f`` where ``M`` is a lightfit module imported under a name — against
the library as it is, in a fresh interpreter that imports modules but runs no script.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHECK = textwrap.dedent(
    r"""
    import ast, importlib, sys
    from pathlib import Path

    root = Path(sys.argv[1])
    sys.path[:0] = [str(root / "benchmarks"), str(root / "experiments")]
    import lightfit  # noqa: F401  (before Dr.Jit, as every script does)

    def module(name):
        return importlib.import_module(name)

    def ours(name):
        return name == "lightfit" or name.startswith("lightfit.") or (root / "benchmarks" / f"{name}.py").exists() \
            or (root / "experiments" / f"{name}.py").exists()

    problems = []
    scripts = sorted((root / "experiments").glob("*.py")) + sorted((root / "benchmarks").glob("*.py"))
    for path in scripts:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        aliases = {}  # a local name bound to one of lightfit's modules
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and ours(node.module):
                try:
                    m = module(node.module)
                except ImportError as err:
                    problems.append(f"{path.name}:{node.lineno}: import {node.module}: {err}")
                    continue
                for a in node.names:
                    if a.name == "*":
                        continue
                    if hasattr(m, a.name):
                        if isinstance(getattr(m, a.name), type(sys)):
                            aliases[a.asname or a.name] = getattr(m, a.name)
                        continue
                    try:  # a submodule: from lightfit.model import emulator
                        aliases[a.asname or a.name] = module(f"{node.module}.{a.name}")
                    except ImportError:
                        problems.append(f"{path.name}:{node.lineno}: {node.module} has no {a.name!r}")
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if ours(a.name):
                        try:
                            m = module(a.name)
                        except ImportError as err:
                            problems.append(f"{path.name}:{node.lineno}: import {a.name}: {err}")
                            continue
                        if a.asname:
                            aliases[a.asname] = m
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
                m = aliases[node.value.id]
                if not hasattr(m, node.attr) and isinstance(node.ctx, ast.Load):
                    problems.append(f"{path.name}:{node.lineno}: {m.__name__} has no {node.attr!r}")
    print("\n".join(sorted(set(problems))))
    print(f"checked {len(scripts)} scripts")
    """
)


def test_every_name_a_script_takes_from_lightfit_exists():
    r = subprocess.run([sys.executable, "-c", CHECK, str(ROOT)], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.strip().splitlines()
    assert lines[-1].startswith("checked ") and int(lines[-1].split()[1]) >= 40, r.stdout
    assert lines[:-1] == [], "\n".join(lines[:-1])
