"""Run the anchor-weights notebook on a run directory and show what it found, in the terminal.

    python -m hispo_pl.notebook runs/pointmaze-1/seed0 [--out FILE.ipynb] [--copy DIR]

The notebook (``anchor_weights.ipynb``) ships with the package as ``hispo_pl.notebooks``. It is
executed headless on ``RUN_DIR``; what its cells print is echoed, the figures it saves go to
``RUN_DIR/figures/`` (listed at the end), and the executed notebook, outputs included, is
written to ``RUN_DIR/figures/anchor_weights.ipynb`` (or ``--out``) to open in Jupyter or an
editor. ``jupyter execute`` runs a notebook without showing or keeping any output. ``--copy DIR``
copies the notebook itself into ``DIR`` to edit and open in Jupyter, without running it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from importlib import resources
from pathlib import Path

from .errors import UserError

NOTEBOOK = "anchor_weights.ipynb"


def notebook_path() -> Path:
    """The shipped notebook: the package's (``notebooks/`` of a checkout, mapped to
    ``hispo_pl.notebooks``), or ``notebooks/`` beside the package in an editable install made
    before the notebook was packaged."""
    try:
        return Path(str(resources.files("hispo_pl.notebooks"))) / NOTEBOOK
    except ModuleNotFoundError:
        return Path(__file__).resolve().parents[1] / "notebooks" / NOTEBOOK


def copy_notebook(folder: Path) -> Path:
    """Copy the shipped notebook into ``folder`` (made if missing); an existing copy there is
    kept, as a user's edits may be in it. Returns its path."""
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / NOTEBOOK
    if target.exists():
        raise UserError(f"{target} exists already; remove it or pick another folder")
    shutil.copyfile(notebook_path(), target)
    return target


def _require_jupyter():
    """nbclient, nbformat and an IPython kernel, or a one-line error saying how to get them."""
    try:
        import ipykernel  # noqa: F401  (the kernel the notebook runs in)
        import nbformat
        from nbclient import NotebookClient
    except ImportError as err:
        raise UserError(
            f"running the notebook needs Jupyter's client and kernel ({err.name} is missing): "
            "pip install 'hispo-pl[notebook]'"
        ) from None
    return nbformat, NotebookClient


def run_notebook(run_dir: Path, out: Path | None = None, echo=print) -> Path:
    """Execute the notebook on ``run_dir``, echo what its cells print (and an error's last
    line), and write the executed notebook to ``out`` (default:
    ``run_dir/figures/anchor_weights.ipynb``). Returns where it was written.

    Raises:
        UserError: no such run directory, Jupyter missing, or a cell failed (its message)."""
    nbformat, NotebookClient = _require_jupyter()
    from nbclient.exceptions import CellExecutionError

    run_dir = run_dir.expanduser().resolve()
    if not run_dir.is_dir():
        raise UserError(f"{run_dir}: no such run directory (a stream's, e.g. runs/demo/seed0)")
    out = out or run_dir / "figures" / NOTEBOOK
    nb = nbformat.read(notebook_path(), as_version=4)
    client = NotebookClient(
        nb,
        timeout=600,
        kernel_name="python3",
        resources={"metadata": {"path": str(run_dir)}},
        extra_arguments=["--IPKernelApp.log_level=ERROR"],  # not its transport warning
    )
    before = os.environ.get("RUN_DIR")
    os.environ["RUN_DIR"] = str(run_dir)  # the kernel inherits the environment
    try:
        client.execute()
        failure = None
    except CellExecutionError as err:
        failure = err
    finally:
        if before is None:
            os.environ.pop("RUN_DIR", None)
        else:
            os.environ["RUN_DIR"] = before
    for cell in nb.cells:
        for output in cell.get("outputs", []):
            if output.get("output_type") == "stream":
                for line in output["text"].rstrip("\n").splitlines():
                    echo(line)
    if failure is not None:
        reason = str(failure).strip().splitlines()
        raise UserError(f"the notebook stopped: {reason[-1] if reason else failure}")
    out.parent.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, out)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m hispo_pl.notebook", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("run_dir", type=Path, nargs="?", help="a stream's run directory")
    parser.add_argument("--out", type=Path, help="where the executed notebook is written")
    parser.add_argument("--copy", type=Path, metavar="DIR", help="copy the notebook, not run it")
    args = parser.parse_args(argv)
    try:
        if args.copy is not None:
            print(f"copied the notebook to {copy_notebook(args.copy)}")
            return 0
        if args.run_dir is None:
            parser.error("give a run directory (e.g. runs/demo/seed0) or --copy DIR")
        out = run_notebook(args.run_dir, args.out)
    except UserError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"the executed notebook, with its figures: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
