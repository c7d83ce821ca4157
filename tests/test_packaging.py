"""Packaging and layout: declared dependencies match imports; the package layout flows one way.

Both checks read the source with :mod:`ast` (nothing is imported), so they are fast and see
imports inside functions too (the CLI imports its heavy dependencies lazily).
"""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lightfit"

#: Import name → distribution name, where they differ. (A name not listed is its own distribution.)
DISTRIBUTION_OF = {
    "PIL": "pillow",
    "plantbox": "cplantbox",
    "yaml": "pyyaml",
    "sklearn": "scikit-learn",
    "skimage": "scikit-image",
    "cv2": "opencv-python",
    "distributed": "dask",  # declared as dask[distributed]; the extra installs `distributed`
}

#: Declared dependencies that lightfit never imports by name, and why they are needed anyway.
NOT_IMPORTED = {
    "jaxlib": "JAX's compiled backend; jax imports it",
    "karellen-llvm-core": "ships libLLVM for Dr.Jit's CPU backend; light/backend.py finds it by path",
    "h5netcdf": "xarray's netCDF engine, named as engine='h5netcdf'",
}


def normalize(name: str) -> str:
    """PEP 503 normalised distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


def declared_dependencies(pyproject: Path) -> set[str]:
    """Normalised distribution names of ``[project].dependencies`` (extras and versions dropped)."""
    deps = tomllib.loads(pyproject.read_text())["project"]["dependencies"]
    return {normalize(re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", d).group(1)) for d in deps}


def module_name(path: Path, root: Path) -> str:
    """Dotted module name of ``path`` (a file under ``root``'s parent package tree)."""
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path, root: Path) -> set[str]:
    """Absolute dotted names ``path`` imports (relative imports resolved), anywhere in the file.

    ``importlib.import_module("x")`` with a literal name counts as importing ``x``.
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    here = module_name(path, root).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module.split(".")
            else:
                base = package[: len(package) - node.level + 1] + ([node.module] if node.module else [])
            out.add(".".join(base))
            # ``from lightfit import inference`` imports the subpackage: each name may be a module
            out.update(".".join(base + [a.name]) for a in node.names if a.name != "*")
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            out.add(node.args[0].value)
    return out


def third_party_imports(root: Path) -> dict[str, set[str]]:
    """Top-level third-party import names under ``root`` → the modules importing them."""
    own = root.name
    found: dict[str, set[str]] = {}
    for path in sorted(root.rglob("*.py")):
        for name in imports_of(path, root):
            top = name.split(".")[0]
            if top in (own, "__future__") or top in sys.stdlib_module_names:
                continue
            found.setdefault(top, set()).add(module_name(path, root))
    return found


def dependency_mismatches(root: Path, pyproject: Path) -> tuple[dict[str, set[str]], set[str]]:
    """(imported but undeclared: distribution → importing modules, declared but never imported)."""
    declared = declared_dependencies(pyproject)
    used: dict[str, set[str]] = {}
    for top, modules in third_party_imports(root).items():
        used.setdefault(normalize(DISTRIBUTION_OF.get(top, top)), set()).update(modules)
    undeclared = {d: m for d, m in used.items() if d not in declared}
    unused = declared - set(used) - {normalize(n) for n in NOT_IMPORTED}
    return undeclared, unused


def test_imports_and_declared_dependencies_match():
    undeclared, unused = dependency_mismatches(PACKAGE, ROOT / "pyproject.toml")
    assert not undeclared, f"imported by lightfit but not in [project].dependencies: {undeclared}"
    assert not unused, f"declared in [project].dependencies but never imported by lightfit: {sorted(unused)}"
    # The exceptions are still declared (otherwise the list is stale).
    stale = {normalize(n) for n in NOT_IMPORTED} - declared_dependencies(ROOT / "pyproject.toml")
    assert not stale, f"NOT_IMPORTED lists undeclared packages: {sorted(stale)}"


def test_dependency_check_catches_both_directions(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("import numpy\nfrom . import sub\n")
    (pkg / "sub" / "__init__.py").write_text(
        "import os\nfrom PIL import Image\nfrom .mod import x\n\n\ndef f():\n    import undeclared_thing.deep\n"
    )
    (pkg / "sub" / "mod.py").write_text("import importlib\nx = importlib.import_module('plantbox')\n")
    (tmp_path / "pyproject.toml").write_text(
        '[project]\nname = "pkg"\ndependencies = ["numpy>=2", "Pillow>=10", "cplantbox", "never_used[extra]>=1"]\n'
    )
    undeclared, unused = dependency_mismatches(pkg, tmp_path / "pyproject.toml")
    assert undeclared == {"undeclared-thing": {"pkg.sub"}}
    assert unused == {"never-used"}
    assert imports_of(pkg / "sub" / "__init__.py", pkg) >= {"pkg.sub.mod", "os", "PIL", "undeclared_thing.deep"}


# -- layout: the pipeline flows one way ---------------------------------------------------------

#: Rank of each subpackage / top-level module along the pipeline, as tight as the code allows (parts
#: of one rank may not import each other): weather and plant need no other part; the light needs the
#: plants; photosynthesis stands beside the light (neither imports the other); the model couples
#: them; inference, distributed runs and datasets use the model (none imports another); ``report``
#: draws what inference and the model give and ``replication`` runs, below it. A module may import
#: its own part and lower ranks, never another part of its rank or a higher one. ``errors``,
#: ``precision``, ``progress`` … are shared helpers, and the package root (``import lightfit``) sets
#: up the Mitsuba backend; all may be imported anywhere.
RANK = {
    "weather": 0,
    "plant": 0,
    "light": 1,
    "photosynthesis": 1,
    "model": 2,
    "inference": 3,
    "distributed": 3,
    "dataset": 3,
    "report": 4,
    "replication": 5,
    "cli": 6,
    "__main__": 7,  # python -m lightfit: the command line
}
SHARED = {"errors", "precision", "progress", "killpoint", "cache", "figure", "constants", "defaults", "files", ""}
#: What the package root (``import lightfit``) may import: the Mitsuba backend it sets up.
ROOT_IMPORTS = {"light"}


def layer_violations(root: Path) -> list[str]:
    """``'importer -> imported'`` for every import of a later part of the pipeline."""
    own = root.name
    bad = []
    for path in sorted(root.rglob("*.py")):
        me = module_name(path, root)
        mine = me.split(".")[1] if "." in me else ""
        for name in sorted(imports_of(path, root)):
            parts = name.split(".")
            if parts[0] != own:
                continue
            theirs = parts[1] if len(parts) > 1 else ""
            if theirs and not ((root / theirs).is_dir() or (root / f"{theirs}.py").exists()):
                continue  # a name from the root, not a module (``from lightfit import __version__``)
            if theirs in SHARED or mine == theirs or (mine == "" and theirs in ROOT_IMPORTS):
                continue
            if mine in SHARED:  # a shared helper may be imported anywhere, so it imports shared helpers only
                bad.append(f"{me} -> {name}")
                continue
            assert mine in RANK and theirs in RANK, f"give {me} / {name} a rank in RANK"
            if RANK[theirs] > RANK[mine] or (RANK[theirs] == RANK[mine] and mine != theirs):
                bad.append(f"{me} -> {name}")
    return bad


def test_layout_flows_one_way():
    assert layer_violations(PACKAGE) == []


@pytest.mark.parametrize(
    ("importer", "source", "ok"),
    [
        ("light/x.py", "from lightfit.model.coupled import CoupledModel\n", False),
        ("photosynthesis/x.py", "def f():\n    import lightfit.inference\n", False),
        ("photosynthesis/x.py", "from lightfit.light import scene\n", False),  # beside the light
        ("light/x.py", "from lightfit.photosynthesis import farquhar\n", False),
        ("plant/x.py", "from lightfit.weather import units\n", False),
        ("weather/x.py", "from lightfit.plant.field import Field\n", False),
        ("light/x.py", "from lightfit.plant.mesh import Mesh\n", True),
        ("distributed/x.py", "from lightfit.inference import calibration\n", False),
        ("report/x.py", "from lightfit.inference import posterior\n", True),
        ("model/x.py", "from lightfit.cli import app\n", False),
        ("model/x.py", "from ..inference import likelihood\n", False),
        ("dataset/x.py", "from lightfit.replication import run\n", False),
        ("model/x.py", "from lightfit.light.bridge import make_irradiance\nfrom lightfit.errors import E\n", True),
        ("cli/x.py", "from lightfit.inference import calibration\n", True),
        ("light/x.py", "from lightfit import inference\n", False),  # the subpackage, by name
        ("light/x.py", "from .. import model\n", False),
        ("cache.py", "from lightfit.inference import likelihood\n", False),  # a shared helper, upward
        ("cache.py", "from lightfit.errors import InputError\n", True),
        ("model/x.py", "from lightfit import __version__\n", True),  # a name, not a module
        ("__init__.py", "from lightfit.light import backend\n", True),  # the root sets up Mitsuba
    ],
)
def test_layout_check_catches_reversed_imports(tmp_path, importer, source, ok):
    pkg = tmp_path / "lightfit"
    for part in RANK:  # the package's parts, as modules the check can see
        (pkg / part).mkdir(parents=True, exist_ok=True)
        (pkg / part / "__init__.py").write_text("")
    for rel in ("__init__.py", importer, "errors.py"):
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text("")
    (pkg / Path(importer).parent / "__init__.py").write_text("")
    (pkg / importer).write_text(source)
    assert (layer_violations(pkg) == []) == ok


def test_tasks_py_says_its_tasks():
    """`python3 tasks.py --help` printed the usage on stderr and exited 1, without bench and setup (a
    newcomer's review): asked, it prints every task and exits 0; an unknown task is named, exit 1.
    Neither sets anything up."""
    import subprocess

    tasks = ROOT / "tasks.py"
    ok = subprocess.run([sys.executable, str(tasks), "--help"], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0 and ok.stderr == "", ok.stderr
    for task in ("run", "test", "setup", "bench"):
        assert f"python3 tasks.py {task}" in ok.stdout
    bad = subprocess.run([sys.executable, str(tasks), "nope"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1 and bad.stderr.startswith("tasks.py: unknown task 'nope'"), bad.stderr


def test_tasks_py_relative_venv_is_the_callers(tmp_path):
    """`LIGHTFIT_VENV=rel python3 /repo/tasks.py setup` from another directory made the venv in the
    repository (venv ran there) but wrote its install stamp under the caller's directory: it installed
    everything, then failed with FileNotFoundError, every time. A relative path is the caller's."""
    import os
    import subprocess

    env = {**os.environ, "LIGHTFIT_VENV": "rel", "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", "import tasks; print(tasks.VENV, tasks.STAMP, sep='\\n')"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout.split("\n")
    assert Path(out[0]) == tmp_path / "rel" and Path(out[1]).parent == tmp_path / "rel"


def test_tasks_py_reinstalls_a_venv_remade_by_another_python(tmp_path, monkeypatch):
    """The install stamp was the lock file's and pyproject's hash alone: a venv that `python3 -m venv`
    remade over the old one for another Python (its python3.11 gone after an upgrade) kept a matching
    stamp and none of its packages. The interpreter the venv runs is part of the stamp now."""
    import importlib.util
    import os

    spec = importlib.util.spec_from_file_location("tasks_under_test", ROOT / "tasks.py")
    tasks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tasks)
    (tmp_path / "a").write_text("")
    (tmp_path / "b").write_text("")
    monkeypatch.setattr(tasks, "BIN", tmp_path / "bin")
    (tmp_path / "bin").mkdir()
    os.symlink(tmp_path / "a", tmp_path / "bin" / "python")
    first = tasks._fingerprint()
    assert tasks._fingerprint() == first  # the same venv: no reinstall
    (tmp_path / "bin" / "python").unlink()
    os.symlink(tmp_path / "b", tmp_path / "bin" / "python")
    assert tasks._fingerprint() != first


def _tasks_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("tasks_under_test", ROOT / "tasks.py")
    tasks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tasks)
    return tasks


@pytest.mark.parametrize("python", ["gone", "3 12", "3 11"])
def test_tasks_py_remakes_a_venv_whose_python_is_gone_or_changed(tmp_path, monkeypatch, python):
    """A venv made by a Python that was then removed (bin/python a dangling link) or that now runs
    another X.Y (/usr/bin/python3 upgraded under it) was kept: `python3 -m venv` left the dangling link
    (then failed, and tasks.py told to install python3-venv), or nothing was remade and pip was run by
    a Python that sees none of the venv's packages ("No module named pip"). Such a venv is made anew
    (`venv --clear`); one whose Python still is the one in pyvenv.cfg is left alone."""
    tasks = _tasks_module()
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "pyvenv.cfg").write_text("home = /nowhere\ninclude-system-site-packages = false\nversion = 3.11.7\n")
    if python == "gone":
        (venv / "bin" / "python").symlink_to(tmp_path / "removed-python3.11")
    else:  # a stand-in interpreter answering the version query with "X Y"
        (venv / "bin" / "python").write_text(f"#!/bin/sh\necho {python}\n")
        (venv / "bin" / "python").chmod(0o755)
    monkeypatch.setattr(tasks, "VENV", venv)
    monkeypatch.setattr(tasks, "BIN", venv / "bin")
    ran = []
    monkeypatch.setattr(tasks, "_sh", lambda *cmd: ran.append([str(c) for c in cmd]))
    tasks._make_venv()
    if python == "3 11":
        assert ran == []
    else:
        assert ran == [[sys.executable, "-m", "venv", "--clear", str(venv)]]


def test_tasks_py_run_takes_paths_from_the_callers_directory(tmp_path, monkeypatch):
    """`cd ~/data && python3 ~/lightfit/tasks.py run --weather SE_EC_001.csv` ran `lightfit replicate`
    in the repository, so the file beside the user was "no such weather file" and `--out` went into
    the repository. It runs in the caller's directory now; with no options the results still go to
    the repository's results/2016-04-20."""
    tasks = _tasks_module()
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    log = tmp_path / "log"
    (bin_ / "lightfit").write_text(f'#!/bin/sh\necho "$PWD" "$@" >> {log}\n[ "$2" != --weather ] || test -f "$3"\n')
    (bin_ / "lightfit").chmod(0o755)
    caller = tmp_path / "data"
    caller.mkdir()
    (caller / "SE_EC_001.csv").write_text("a weather export\n")
    monkeypatch.setattr(tasks, "BIN", bin_)
    monkeypatch.setattr(tasks, "setup", lambda: None)
    monkeypatch.chdir(caller)
    tasks.main(["run", "--weather", "SE_EC_001.csv", "--out", "results/real"])  # fails if the file is not found
    tasks.main(["run"])
    first, second = log.read_text().splitlines()
    assert first == f"{caller} replicate --weather SE_EC_001.csv --out results/real"
    assert second.split()[1:] == ["replicate", "--out", str(ROOT / "results" / "2016-04-20")]


def test_tasks_py_says_why_the_install_may_have_failed(tmp_path, monkeypatch, capsys):
    """A failed install (no network, or a Python the lock has no wheels for) ended with pip's message
    alone and exit 1: tasks.py now adds what the two usual causes look like, naming this Python."""
    import subprocess

    tasks = _tasks_module()
    monkeypatch.setattr(tasks, "_make_venv", lambda: None)
    monkeypatch.setattr(tasks, "STAMP", tmp_path / "stamp")
    monkeypatch.setattr(tasks, "BIN", tmp_path / "bin")

    def fail(*args):
        raise subprocess.CalledProcessError(1, ["pip", "install", *args])

    monkeypatch.setattr(tasks, "_install", fail)
    with pytest.raises(subprocess.CalledProcessError):
        tasks.setup()
    err = capsys.readouterr().err
    ver = f"{sys.version_info.major}.{sys.version_info.minor}"
    assert f"for Python {ver}" in err and "network" in err and "made and tested with Python 3.11" in err
    assert not (tmp_path / "stamp").exists()  # nothing claims to be installed


def test_the_declared_licence_has_its_text():
    """pyproject declares BSD-3-Clause and names LICENSE as its file: the file is there, is that
    licence (its title and the third clause, the one BSD-2 lacks) and is shipped (license-files)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "BSD-3-Clause" and project["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License")
    assert "Neither the name of the copyright holder nor the names of its" in text
