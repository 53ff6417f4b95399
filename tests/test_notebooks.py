"""Execute every jupytext notebook in notebooks/ on a short horizon so none of them rots, and check
that each notebook that draws shows its figures inline (issue 16: a notebook whose figures went
only to files, or to a non-inline backend, ran "successfully" while showing nothing).

Each notebook reads ``ROBUST_DRAKE_SHORT=1`` (set in conftest.py) to shorten its runs.
"""

import os
import pathlib
import re

import jupytext
import pytest
from nbclient import NotebookClient

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.py"))
# A notebook "plots" when its code draws with matplotlib (pyplot or the package's plot helpers).
PLOTS = re.compile(r"plt\.(subplots|figure|imshow|plot)\(|\.plot\(|plot_[a-z_]+\(|_figures?\(")


def _images(cell) -> int:
    return sum(1 for o in cell.get("outputs", [])
               if o.get("output_type") in ("display_data", "execute_result") and "image/png" in o.get("data", {}))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes_and_shows_its_figures(path, tmp_path):
    nb = jupytext.read(path)
    os.environ["ROBUST_DRAKE_SHORT"] = "1"
    os.environ["ROBUST_DRAKE_NOTEBOOK_OUT"] = str(tmp_path)
    # the kernel picks its own (inline) backend; a value inherited from the test process must not win
    os.environ.pop("MPLBACKEND", None)
    client = NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(REPO)}})
    client.execute()
    code = [c for c in nb.cells if c.cell_type == "code"]
    errors = [o for c in code for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
    # every cell that draws shows at least one PNG inline (skipped cells, e.g. `if not SHORT:`, excepted)
    drawing = [c for c in code if PLOTS.search(c.source) and "if not SHORT" not in c.source
               and not re.search(r"^def ", c.source, re.M)]  # a cell defining a helper draws nothing yet
    blank = [c.source.splitlines()[0] for c in drawing if _images(c) == 0]
    assert drawing, "no drawing cell found: update PLOTS"
    assert not blank, f"cells that draw but show no image: {blank}"
