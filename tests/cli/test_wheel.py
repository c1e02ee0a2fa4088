"""hispo-pl installed from its wheel, outside the checkout, as a user gets it: the package's
metadata (licence, project links), the configs it ships, and the three commands a new user
runs first (``config copy``, ``benchmark --dry-run``, ``fit`` of a stream), each run from a
directory that holds no checkout."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
from helpers import ROOT, TINY_STREAM

SOURCES = (
    "pyproject.toml",
    "README.md",
    "LICENSE",
    "hispo_pl",
    "configs",
    "notebooks",
)
IGNORE = {"ignore": shutil.ignore_patterns("__pycache__"), "symlinks": True}
CLEAN_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # no checkout on the path


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory) -> tuple[Path, Path]:
    """The wheel built from this checkout, and a fresh venv with it installed (its
    dependencies are this interpreter's, read through a ``.pth``: no download)."""
    root = tmp_path_factory.mktemp("wheel")
    source = root / "source"  # a copy: building in the checkout would leave its egg-info there
    source.mkdir()
    for name in SOURCES:
        copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy
        copy(ROOT / name, source / name, **IGNORE if (ROOT / name).is_dir() else {})
    build = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation"]
    subprocess.run([*build, str(source), "-w", str(root / "dist")], check=True, timeout=300)
    (wheel,) = (root / "dist").glob("hispo_pl-*.whl")
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    install = [str(python), "-m", "pip", "install", "-q", "--no-deps", str(wheel)]
    subprocess.run(install, check=True, timeout=300, cwd=root, env=CLEAN_ENV)
    # after the install (pip would take this interpreter's hispo-pl for the wheel's); the
    # venv's own site-packages stay first on the path
    (Path(purelib) / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return wheel, venv


def _hispo_pl(venv: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(venv / "bin" / "hispo-pl"), *args],
        cwd=cwd,
        env=CLEAN_ENV,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_the_wheel_carries_its_licence_links_and_configs(wheel_venv):
    wheel, _ = wheel_venv
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        (metadata,) = (n for n in names if n.endswith(".dist-info/METADATA"))
        text = z.read(metadata).decode()
    assert "License-Expression: Apache-2.0" in text and "License-File: LICENSE" in text
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert "Project-URL: Paper, https://" in text
    shipped = {n.split("hispo_pl/configs/", 1)[1] for n in names if "hispo_pl/configs/" in n}
    assert {"streams/pointmaze-1.yaml", "methods/hispo.yaml", "grids/paper.yaml"} <= shipped
    assert "hispo_pl/callbacks/anchors.py" in names
    assert "hispo_pl/notebooks/anchor_weights.ipynb" in names  # python -m hispo_pl.notebook
    assert not [n for n in names if n.endswith((".c", ".so"))]  # nothing to compile or load


def test_the_wheel_carries_none_of_the_repositorys_own_tools(wheel_venv):
    """The repository's tools (``lab/``: the paper's figures, the docs pages, the manifests,
    the checkout's commit) stay out of the product: no code in the wheel names a ``docs``
    path or runs ``git``."""
    wheel, _ = wheel_venv
    with zipfile.ZipFile(wheel) as z:
        code = {n: z.read(n).decode() for n in z.namelist() if n.endswith(".py")}
    assert code and not [n for n in code if not n.startswith("hispo_pl/")]
    assert not [n for n, text in code.items() if re.search(r"[\"']docs[/\"']", text)]
    assert not [n for n, text in code.items() if re.search(r"[\"']git[\"']|git log", text)]


@pytest.mark.e2e
def test_a_user_outside_the_checkout_copies_plans_and_fits(wheel_venv, tiny_umaze, tmp_path):
    _, venv = wheel_venv
    here = tmp_path / "work"
    here.mkdir()
    done = _hispo_pl(venv, here, "config", "copy", "configs")
    assert done.returncode == 0 and "copied" in done.stdout, done.stderr
    assert (here / "configs" / "methods" / "hispo.yaml").is_file()

    plan = ["benchmark", "--stream", "pointmaze-1", "--methods", "hispo,scn", "--seeds", "1"]
    done = _hispo_pl(venv, here, *plan, "--out", "bench", "--dry-run")
    assert done.returncode == 0, done.stderr
    assert str(venv) in done.stdout and "hispo/seed0 (to run)" in done.stdout
    assert not (here / "bench" / "runs").exists()  # a dry run trains nothing

    stream = ["--data.stream", json.dumps(TINY_STREAM), "--trainer.max_steps", "5"]
    fit = ["fit", "--config", "configs/streams/pointmaze-1.yaml"]
    fit += ["--config", "configs/methods/hispo.yaml", *stream, "--data.batch_size", "64"]
    fit += ["--trainer.callbacks.init_args.episodes", "2", "--trainer.logger.init_args.save_dir"]
    done = _hispo_pl(venv, here, *fit, "runs", "--trainer.enable_progress_bar", "false")
    assert done.returncode == 0, done.stderr[-2000:]
    results = json.loads((here / "runs/pointmaze-1/seed0/results.json").read_text())
    assert results["stream"] == TINY_STREAM and len(results["R"]) == 2
