"""What every benchmark result records, so that a number can be traced, and where it is written.

A script under benchmarks/ or experiments/ writes its JSON through :func:`write_result` to ``--out``
(:func:`out_option`; default: its tracked file under benchmarks/results/ or experiments/results/,
which the docs cite, so a rerun for a look elsewhere passes ``--out /tmp/x.json``). The record
adds, unless the script set them itself: the commit, whether lightfit/, benchmarks/ or experiments/
had uncommitted changes, the cores, the load average at the start (this module's import, before
the script's work) and the end, and the command line. Absolute times on a shared machine move with
its load: compare settings measured side by side in one run (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The 1-minute load average when the script started (imported before its work begins).
LOAD_AT_START = os.getloadavg()[0]


def _said_not_traced(kind, value, tb) -> None:
    """Every script imports this module: lightfit's refusal of a bad setting (an
    :class:`~lightfit.errors.InputError`, e.g. ``--n-plants -5``) ends it with its one-line message,
    as the command line does, not a traceback through the script; anything else is traced."""
    if any(c.__module__ == "lightfit.errors" and c.__name__ == "InputError" for c in kind.__mro__):
        print(f"error: {value}", file=sys.stderr)
    else:
        sys.__excepthook__(kind, value, tb)


sys.excepthook = _said_not_traced


def commit_state() -> dict:
    """The commit measured, and whether lightfit/, benchmarks/ or experiments/ had uncommitted changes; ``None``
    for each where the tree is no git checkout (the device machine's copy: device_light.py names
    its code by a digest of the sources instead) or git is missing."""
    keys = (
        "lightfit_commit",
        "lightfit_uncommitted_changes",
        "benchmarks_uncommitted_changes",
        "experiments_uncommitted_changes",
    )

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout.strip()

    try:
        commit = git("rev-parse", "--short", "HEAD")
    except FileNotFoundError:
        commit = ""
    if not commit:
        return dict.fromkeys(keys)
    lightfit = bool(git("status", "--porcelain", "lightfit"))
    scripts = [bool(git("status", "--porcelain", d, f":!{d}/results")) for d in ("benchmarks", "experiments")]
    return dict(zip(keys, (commit, lightfit, *scripts)))


def writable_path(text: str) -> Path:
    """``--out``'s type: a file that can be written (its folder is made and a file tried in it),
    checked when the options are read, so that an unwritable ``--out`` stops the script at once
    with argparse's message, not with a traceback after minutes of work."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a folder, not a file")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except OSError as err:
        raise argparse.ArgumentTypeError(f"{text!r} cannot be written: {err}") from None
    return path


def out_option(parser: argparse.ArgumentParser, default: Path) -> None:
    """``--out``: the JSON to write (default ``default``, the tracked result)."""
    rel = default.resolve().relative_to(ROOT) if default.resolve().is_relative_to(ROOT) else default
    parser.add_argument(
        "--out",
        type=writable_path,
        default=default,
        help=f"JSON to write (default {rel}, the tracked result the docs cite)",
    )


def record() -> dict:
    """The provenance fields :func:`write_result` adds."""
    return {
        **commit_state(),
        "cpu_cores": os.cpu_count(),
        "load_average_start": LOAD_AT_START,
        "load_average_end": os.getloadavg()[0],
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
    }


def wide_console():
    """A rich console for a script's tables: as wide as the terminal, or 200 columns off one (a log,
    a pipe, ``tee``), where rich would cut them to 80."""
    from rich.console import Console

    console = Console()
    return console if console.is_terminal else Console(width=200)


def write_result(path: Path, result: dict, **dump) -> Path:
    """``result`` with :func:`record`'s fields first (the script's own values win) as JSON at ``path``."""
    full = {k: v for k, v in record().items() if k not in result} | result
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(full, **({"indent": 2} | dump)) + "\n")
    return path
