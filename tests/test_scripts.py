"""The experiment and benchmark scripts, and the Python examples in README.md and docs/, still fit
the library they call.

The scripts under experiments/ and benchmarks/ are not run in CI (minutes to hours each), so a
renamed or removed library function would be found only by the next person who runs one (it
happened: docs/model.md records a check script that had stopped working); the docs' examples are
what a newcomer copies first. This test reads every script's and every ```python block's syntax
tree and checks each name it takes from lightfit or from a sibling script — ``from lightfit.x
import f`` and ``from bench_light import g`` anywhere in the file, function bodies included, and
``M.f`` where ``M`` is a lightfit module imported under a name — and each call of such a name
against its signature (the positional count and keyword names, as ``inspect.Signature.bind``
takes them), against the library as it is, in a fresh interpreter that imports modules but runs
no script.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHECK = textwrap.dedent(
    r"""
    import ast, importlib, inspect, re, sys
    from pathlib import Path

    root = Path(sys.argv[1])
    sys.path[:0] = [str(root / "benchmarks"), str(root / "experiments")]
    import lightfit  # noqa: F401  (before Dr.Jit, as every script does)

    def module(name):
        return importlib.import_module(name)

    def ours(name):
        return name == "lightfit" or name.startswith("lightfit.") or (root / "benchmarks" / f"{name}.py").exists() \
            or (root / "experiments" / f"{name}.py").exists()

    def call_problem(obj, call):  # why the call cannot bind to obj's signature (None: it can, or cannot be told)
        if any(isinstance(a, ast.Starred) for a in call.args) or any(k.arg is None for k in call.keywords):
            return None  # *args / **kwargs: not checkable by count
        try:
            sig = inspect.signature(obj)
        except (TypeError, ValueError):
            return None
        try:
            sig.bind(*[None] * len(call.args), **{k.arg: None for k in call.keywords})
        except TypeError as err:
            return str(err)
        return None

    problems = []
    scripts = sorted((root / "experiments").glob("*.py")) + sorted((root / "benchmarks").glob("*.py"))
    sources = [(p.name, p.read_text(encoding="utf-8"), 0) for p in scripts]  # (file, code, its first line - 1)
    for doc in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        text = doc.read_text(encoding="utf-8")
        for m in re.finditer(r"```python\n(.*?)```", text, re.S):
            sources.append((str(doc.relative_to(root)), m.group(1), text[: m.start()].count(chr(10)) + 1))
    n_docs = len(sources) - len(scripts)
    for path, source, offset in sources:
        name = lambda node: f"{path}:{offset + node.lineno}"  # noqa: E731
        try:
            tree = ast.parse(source)
        except SyntaxError as err:
            problems.append(f"{path}:{offset + (err.lineno or 0)}: not Python: {err.msg}")
            continue
        aliases = {}  # a local name bound to one of lightfit's modules
        objects = {}  # a local name bound to a function or class taken from lightfit
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and ours(node.module):
                try:
                    m = module(node.module)
                except ImportError as err:
                    problems.append(f"{name(node)}: import {node.module}: {err}")
                    continue
                for a in node.names:
                    if a.name == "*":
                        continue
                    if hasattr(m, a.name):
                        if isinstance(getattr(m, a.name), type(sys)):
                            aliases[a.asname or a.name] = getattr(m, a.name)
                        elif callable(getattr(m, a.name)):
                            objects[a.asname or a.name] = getattr(m, a.name)
                        continue
                    try:  # a submodule: from lightfit.model import emulator
                        aliases[a.asname or a.name] = module(f"{node.module}.{a.name}")
                    except ImportError:
                        problems.append(f"{name(node)}: {node.module} has no {a.name!r}")
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if ours(a.name):
                        try:
                            m = module(a.name)
                        except ImportError as err:
                            problems.append(f"{name(node)}: import {a.name}: {err}")
                            continue
                        if a.asname:
                            aliases[a.asname] = m
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
                m = aliases[node.value.id]
                if not hasattr(m, node.attr) and isinstance(node.ctx, ast.Load):
                    problems.append(f"{name(node)}: {m.__name__} has no {node.attr!r}")
            if isinstance(node, ast.Call):
                f, obj = node.func, None
                if isinstance(f, ast.Name) and f.id in objects:
                    obj, said = objects[f.id], f.id
                elif isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id in aliases:
                    obj, said = getattr(aliases[f.value.id], f.attr, None), f"{f.value.id}.{f.attr}"
                why = None if obj is None or not callable(obj) else call_problem(obj, node)
                if why:
                    problems.append(f"{name(node)}: {said}(...): {why}")
    print("\n".join(sorted(set(problems))))
    print(f"checked {len(scripts)} scripts and {n_docs} examples in the docs")
    """
)


def test_every_name_a_script_or_docs_example_takes_from_lightfit_exists():
    r = subprocess.run([sys.executable, "-c", CHECK, str(ROOT)], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.strip().splitlines()
    assert lines[-1].startswith("checked ") and int(lines[-1].split()[1]) >= 40, r.stdout
    assert int(lines[-1].split()[4]) >= 12, r.stdout  # the ```python blocks of README.md and docs/
    assert lines[:-1] == [], "\n".join(lines[:-1])


def test_model_md_an_noise_bias_table_reads_its_stored_json():
    """docs/model.md's "Measured" table of experiments/an_noise_bias.py quotes
    experiments/results/an_noise_bias.json: every percentage is the JSON's value rounded to the
    two decimals shown (its 64-sample row once read canopy APAR ± 0.03 % for a stored 0.0247 %)."""
    import json
    import re

    res = json.loads((ROOT / "experiments" / "results" / "an_noise_bias.json").read_text())
    text = (ROOT / "docs" / "model.md").read_text()
    an, apar = res["canopy_an"], res["canopy_apar"]
    for k in ("32", "64", "512"):
        row = next(line for line in text.splitlines() if re.match(rf"\| {k}\b[^|]*\| [−+*\d]", line))
        cells = [re.findall(r"[−+]?\d+\.\d+", c) for c in row.strip("|").split("|")[1:]]
        shown = [[float(x.replace("−", "-")) for x in c] for c in cells]
        expected = [
            [100 * an["relative_bias"][k], 100 * an["relative_bias_se"][k]],
            [100 * an["relative_predicted_bias"][k]],
            [100 * x for x in an["relative_reported_mc_sd_one_run_bounds"][k]],
            [100 * apar["relative_bias"][k], 100 * apar["relative_bias_se"][k]],
        ]
        for got, want in zip(shown, expected, strict=True):
            assert got == [round(w, 2) for w in want], (k, row)
