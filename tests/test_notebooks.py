"""Every notebook ships executed (with its outputs and plots), and re-executes headless in its
reduced-size mode (``JAXSIM_NOTEBOOK_FAST=1``)."""

import os
import pathlib

import pytest

from _compile_flags import with_fast_compile

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = sorted((pathlib.Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


def test_notebooks_exist():
    names = [p.name for p in NOTEBOOKS]
    assert {"01_inverse_kinematics.ipynb", "02_cloth.ipynb", "03_differentiable.ipynb"} <= set(names)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebooks_ship_executed(path):
    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.get("execution_count") for c in code), f"{path.name} has cells that were not run"
    assert not any(o.get("output_type") == "error" for c in code for o in c.get("outputs", []))
    kinds = {k for c in code for o in c.get("outputs", []) for k in o.get("data", {})}
    plots = any("plt." in "".join(c.source) for c in code)
    assert "image/png" in kinds or not plots, f"{path.name} draws plots but ships none"


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, monkeypatch, tmp_path):
    monkeypatch.setenv("JAXSIM_NOTEBOOK_FAST", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("XLA_FLAGS", with_fast_compile(os.environ)["XLA_FLAGS"])
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:  # run afresh, not the shipped outputs
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError on any failing cell
    printed = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "nan" not in printed.lower().replace("nanoseconds", "")
