"""The atlas visualisation notebook: committed without outputs, in sync with its jupytext twin, and
executed headless with nbmake on the tiny run it trains itself."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOK = NOTEBOOKS / "atlas_visualisation.ipynb"
TWIN = NOTEBOOKS / "atlas_visualisation.py"
FIGURES = ["atlases", "alpha_mattes", "uv_checkerboard", "crf", "exposures", "blur_kernels", "exposure_sweep"]


def test_committed_notebook_has_no_outputs():
    nbformat = pytest.importorskip("nbformat")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code, "the notebook has no code cells"
    for c in code:
        assert c.outputs == [], (f"outputs left in a cell starting {c.source[:40]!r}: run "
                                 f"`jupytext --to ipynb {TWIN.name}` to strip")
        assert c.execution_count is None
        assert "execution" not in c.metadata


def test_notebook_matches_its_text_twin():
    jupytext = pytest.importorskip("jupytext")
    nbformat = pytest.importorskip("nbformat")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    twin = jupytext.read(TWIN)
    cells = lambda n: [(c.cell_type, c.source.strip()) for c in n.cells]  # noqa: E731
    assert cells(nb) == cells(twin), (f"{NOTEBOOK.name} and {TWIN.name} differ: edit the .py, then "
                                      f"`jupytext --sync {TWIN.name}`")
    params = [c for c in nb.cells if "parameters" in c.metadata.get("tags", [])]
    assert len(params) == 1 and "RUN = " in params[0].source


@pytest.mark.timeout(900)  # a kernel that trains a tiny run first; nbmake's own limit is 600 s
def test_notebook_runs_headless_with_nbmake(tmp_path):
    for mod in ("nbmake", "ipykernel", "nbclient"):
        pytest.importorskip(mod)
    env = {k: v for k, v in os.environ.items() if k not in ("LAYERCAM_RUN", "LAYERCAM_CRF_TRUTH")}
    # the tiny run goes to a temp folder: under tmp_path, so that pytest cleans it up
    env.update(LAYERCAM_FIGURE_DIR=str(tmp_path / "figures"), OMP_NUM_THREADS="1", TMPDIR=str(tmp_path))
    cmd = [sys.executable, "-m", "pytest", "--nbmake", "--nbmake-timeout=600", str(NOTEBOOK), "-q",
           "-p", "no:cacheprovider", "-o", "addopts=", "-o", "timeout=0"]
    res = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-2000:]
    saved = sorted(p.name for p in (tmp_path / "figures").glob("*.png"))
    assert saved == [f"{i:02d}_{name}.png" for i, name in enumerate(FIGURES, 1)]
    assert all((tmp_path / "figures" / n).stat().st_size > 5000 for n in saved)
