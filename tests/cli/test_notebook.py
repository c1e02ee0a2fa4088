"""notebooks/anchor_weights.ipynb executed end to end on a tiny real 3-task HiSPO run."""

from __future__ import annotations

import json
from pathlib import Path

import nbformat
import pytest
from helpers import fit_tiny_stream
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOK = ROOT / "notebooks" / "anchor_weights.ipynb"
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-IA[3]", "pointmaze-umaze-PO[3]"]
# the whole list in one value: a dotted --trainer.callbacks.init_args.X reaches only the last one.
# eps 0 keeps a new anchor unless the previous subspace does at least as well, so that the third
# task can search a simplex over two previous anchors and a subspace can end with 3 anchors.
CALLBACKS = [
    {"class_path": "hispo_pl.callbacks.AnchorExtension"},
    {
        "class_path": "hispo_pl.callbacks.DirichletEvaluation",
        "init_args": {"n_candidates": 64, "n_batches": 2},
    },
    {
        "class_path": "hispo_pl.callbacks.SubspacePruning",
        "init_args": {"eps_high": 0.0, "eps_low": 0.0},
    },
    {"class_path": "hispo_pl.callbacks.RolloutEvaluation", "init_args": {"episodes": 2}},
]


def _execute(run_dir: Path, monkeypatch) -> nbformat.NotebookNode:
    """Run the notebook as ``jupyter nbconvert --execute`` would (cwd: its folder)."""
    monkeypatch.setenv("RUN_DIR", str(run_dir))  # the kernel inherits the environment
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's inline backend
    nb = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(
        nb,
        timeout=300,
        kernel_name="python3",
        resources={"metadata": {"path": str(NOTEBOOK.parent)}},
    ).execute()
    return nb


def test_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)


@pytest.mark.e2e
def test_notebook_plots_a_real_stream_run(tiny_umaze, tmp_path, monkeypatch):
    callbacks = ("--trainer.callbacks", json.dumps(CALLBACKS))
    results, run_dir = fit_tiny_stream("hispo", tmp_path, STREAM, *callbacks)
    assert results["stream"] == STREAM
    decisions = [
        json.loads(line) for line in (run_dir / "decisions.jsonl").read_text().splitlines()
    ]
    assert len(decisions) == 2 * len(STREAM)
    assert {d["eps"] for d in decisions} == {0.0}  # the explicit callbacks list was applied
    # task 3 searched the simplex over the 2 previous anchors (the newest anchor at 0)
    searched = sorted((run_dir / "search").glob("task_03_*.npz"))
    assert searched, "no Dirichlet search for task 3"

    nb = _execute(run_dir, monkeypatch)
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    images = [o for c in nb.cells for o in c.get("outputs", []) if "image/png" in o.get("data", {})]
    figures = {p.name for p in (run_dir / "figures").glob("*.png")}
    assert len(images) == len(figures)  # every saved figure is also shown inline

    subspaces = results["anchors"]
    assert set(subspaces) == {"high", "low"}
    expected = {f"alpha_bars_{name}.png" for name in subspaces} | {"anchors.png", "R_heatmap.png"}
    expected |= {f"search_{p.stem}.png" for p in (run_dir / "search").glob("*.npz")}
    expected |= {f"simplex_{name}.png" for name, k in subspaces.items() if k == 3}
    assert {f"search_{p.stem}.png" for p in searched} <= expected
    assert figures == expected

    # as a user runs it: what the cells print shows, the executed notebook keeps its outputs
    from hispo_pl.notebook import run_notebook

    printed: list[str] = []
    written = run_notebook(run_dir, echo=printed.append)
    assert printed[0] == f"run: {run_dir.resolve()}"
    assert any(line.startswith("figures: R_heatmap.png") for line in printed)
    assert written == run_dir.resolve() / "figures" / "anchor_weights.ipynb"
    executed = nbformat.read(written, as_version=4)
    shown = [
        o for c in executed.cells for o in c.get("outputs", []) if "image/png" in o.get("data", {})
    ]
    assert len(shown) == len(figures)


def test_the_notebook_ships_and_copies_without_a_run(tmp_path, capsys):
    from hispo_pl.notebook import main, notebook_path

    assert notebook_path().read_bytes() == NOTEBOOK.read_bytes()
    assert main(["--copy", str(tmp_path / "mine")]) == 0
    assert (tmp_path / "mine" / "anchor_weights.ipynb").read_bytes() == NOTEBOOK.read_bytes()
    assert main(["--copy", str(tmp_path / "mine")]) == 2  # a copy there (maybe edited) is kept
    assert main([str(tmp_path / "no-run")]) == 2
    assert "no such run directory" in capsys.readouterr().err


def test_notebook_says_how_to_make_a_run(tmp_path, monkeypatch):
    with pytest.raises(CellExecutionError) as info:
        _execute(tmp_path / "no-run", monkeypatch)
    message = str(info.value)
    assert "has no results.json" in message
    assert "hispo-pl fit --config configs/streams/pointmaze-1.yaml" in message
