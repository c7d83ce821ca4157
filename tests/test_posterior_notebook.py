"""notebooks/posterior_analysis.ipynb executes on the tiny saved run (tests/fixtures/posterior_tiny.h5)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "notebooks" / "posterior_analysis.ipynb"
FIXTURE = ROOT / "tests" / "fixtures" / "posterior_tiny.h5"


def test_fixture_is_small():
    assert FIXTURE.exists() and FIXTURE.stat().st_size < 1_000_000


def test_notebook_executes(tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    from jupyter_client.kernelspec import KernelSpecManager, NoSuchKernel

    try:  # ipykernel's native 'python3' spec runs this interpreter (the venv)
        KernelSpecManager().get_kernel_spec("python3")
    except NoSuchKernel:
        pytest.skip("no python3 kernel spec (install ipykernel)")
    monkeypatch.setenv("LIGHTFIT_POSTERIOR_RUN", str(FIXTURE))
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        nb, kernel_name="python3", timeout=120, resources={"metadata": {"path": str(NOTEBOOK.parent)}}
    )
    client.execute()
    errors = [
        o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.get("output_type") == "error"
    ]
    assert not errors
    assert os.environ["LIGHTFIT_POSTERIOR_RUN"] == str(FIXTURE)
