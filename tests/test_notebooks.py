"""Execute every jupytext notebook in notebooks/ on a short horizon so none of them rots.

Each notebook reads ``ROBUST_DRAKE_SHORT=1`` (set in conftest.py) to shorten its runs.
"""

import os
import pathlib

import jupytext
import pytest
from nbclient import NotebookClient

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.py"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path):
    nb = jupytext.read(path)
    os.environ["ROBUST_DRAKE_SHORT"] = "1"
    os.environ["ROBUST_DRAKE_NOTEBOOK_OUT"] = str(tmp_path)
    client = NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(REPO)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
