#!/usr/bin/env python3
"""Set up lightfit and run its two entry points, needing only Python >= 3.11.

    python3 tasks.py run     # set up, then run the main job (20 April 2016, bundled data, CPU)
    python3 tasks.py run [lightfit replicate options]   # paths in them are the caller's directory's
    python3 tasks.py test    # set up, then lint (ruff) and run the test suite
    python3 tasks.py setup   # set up only (.venv)
    python3 tasks.py bench   # set up, then every benchmarks/bench_*.py (long: see docs/benchmarks.md)

Setup is idempotent: the virtual environment ``.venv`` is (re)installed only when
``requirements.lock``, ``pyproject.toml`` or its Python changed since the last install. A Makefile
would do the same, but `make` is not on a bare Debian/Ubuntu image and Python is.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
# A relative LIGHTFIT_VENV is taken from the caller's directory, once: the commands below run in ROOT.
VENV = Path(os.environ.get("LIGHTFIT_VENV", ROOT / ".venv")).absolute()
BIN = VENV / "bin"
STAMP = VENV / ".lightfit-installed"


def _sh(*cmd: str | Path, cwd: Path = ROOT) -> None:
    print("+", " ".join(map(str, cmd)), flush=True)
    subprocess.run([str(c) for c in cmd], check=True, cwd=cwd)


def _install(*args: str) -> None:
    """pip install, its build-backend chatter (setuptools notices) shown only if it fails."""
    cmd = [str(BIN / "python"), "-m", "pip", "install", "--quiet", *args]
    print("+", " ".join(cmd), flush=True)
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if r.returncode:
        sys.stdout.write(r.stdout)
        sys.stderr.write(r.stderr)
        raise subprocess.CalledProcessError(r.returncode, cmd)


def _fingerprint() -> str:
    h = hashlib.sha256()
    for name in ("requirements.lock", "pyproject.toml"):
        h.update((ROOT / name).read_bytes())
    # and the interpreter the venv runs: one remade by another Python (python3 upgraded to 3.12) has
    # none of the packages installed for the old one, which the stamp alone would not notice
    h.update(os.path.realpath(BIN / "python").encode())
    return h.hexdigest()


def _venv_python_changed() -> bool:
    """Whether the venv's ``python`` can no longer run what was installed for it: its interpreter was
    removed (a dangling link, which ``python3 -m venv`` leaves as it is) or it now runs another
    Python X.Y than the venv was made for (``pyvenv.cfg``; ``/usr/bin/python3`` upgraded), which sees
    none of the venv's packages, pip included."""
    py = BIN / "python"
    if not py.exists():
        return os.path.lexists(py)
    cfg = VENV / "pyvenv.cfg"
    made = re.search(r"^version(?:_info)?\s*=\s*(\d+)\.(\d+)", cfg.read_text(), re.M) if cfg.exists() else None
    if made is None:
        return False
    ran = subprocess.run([str(py), "-c", "import sys; print(*sys.version_info[:2])"], capture_output=True, text=True)
    return ran.returncode != 0 or ran.stdout.split() != list(made.groups())


def _make_venv() -> None:
    changed = _venv_python_changed()
    if (BIN / "python").exists() and not changed:
        return
    if changed:
        print(f"tasks.py: the Python {VENV} was made with is gone or changed; making it anew", flush=True)
    try:
        _sh(sys.executable, "-m", "venv", *(["--clear"] if changed else []), VENV)
    except subprocess.CalledProcessError:
        # Debian/Ubuntu split ensurepip into python3-venv; install it if we can.
        shutil.rmtree(VENV, ignore_errors=True)
        if shutil.which("apt-get") and os.geteuid() == 0:
            ver = f"{sys.version_info.major}.{sys.version_info.minor}"
            _sh("apt-get", "update", "-q")
            _sh("apt-get", "install", "-y", "-q", f"python{ver}-venv")
            _sh(sys.executable, "-m", "venv", VENV)
        else:
            sys.exit("tasks.py: `python3 -m venv` failed; install the python3-venv package and retry")


#: The pip that installs the lock (the one the lock was tested with): an unpinned upgrade could
#: bring a pip that resolves or builds the lock differently on a later day.
PIP = "pip==26.3"


def setup() -> None:
    if sys.version_info < (3, 11):  # noqa: UP036 — tasks.py runs under any python3
        sys.exit(f"tasks.py: lightfit needs Python >= 3.11, this is {sys.version.split()[0]}")
    _make_venv()
    if STAMP.exists() and STAMP.read_text() == _fingerprint():
        return
    try:
        _install(PIP)
        _install("-r", "requirements.lock")
        _install("--no-deps", "-e", ".")
    except subprocess.CalledProcessError:
        ver = f"{sys.version_info.major}.{sys.version_info.minor}"
        print(
            f"tasks.py: pip could not install lightfit's locked dependencies for Python {ver} (its message "
            "above). Connection errors or 'from versions: none' mean this machine cannot reach PyPI (no "
            "network, or a proxy or mirror to set: HTTPS_PROXY, PIP_INDEX_URL); 'No matching distribution' "
            f"with versions listed means a pinned package has no build for Python {ver}: requirements.lock "
            "was made and tested with Python 3.11.",
            file=sys.stderr,
            flush=True,
        )
        raise
    STAMP.write_text(_fingerprint())


def main(argv: list[str]) -> None:
    task, *rest = argv or ["help"]
    if task in ("help", "-h", "--help"):  # asked for: the usage on stdout, exit 0
        print(__doc__)
    elif task == "setup":
        setup()
    elif task == "run":
        setup()
        # in the caller's directory, where the paths given after `run` (--weather, --out …) are; the
        # default results still go to the repository's results/2016-04-20
        _sh(BIN / "lightfit", "replicate", *(rest or ["--out", ROOT / "results" / "2016-04-20"]), cwd=Path.cwd())
    elif task == "test":
        setup()
        _sh(BIN / "ruff", "check", ".")
        _sh(BIN / "ruff", "format", "--check", ".")
        _sh(BIN / "python", "-m", "pytest", "-n", "2", "--durations=15", *rest)
    elif task == "bench":
        setup()
        for script in sorted((ROOT / "benchmarks").glob("bench_*.py")):
            _sh(BIN / "python", script, *rest)
    else:
        sys.exit(f"tasks.py: unknown task {task!r}\n{__doc__}")


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except subprocess.CalledProcessError as err:
        sys.exit(err.returncode)
