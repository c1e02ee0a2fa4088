"""Probes for the reliability tests: hispo-pl in a real subprocess, patched to be slow or to
hang at a chosen point, waited on until a file appears, then killed."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import ROOT

TINY_HISPO = """
model:
  class_path: hispo_pl.modules.HiSPO
  init_args: {backbone: {high_hidden: 8, low_hidden: 16, high_log_std: 0.0}}
trainer:
  callbacks:
    - class_path: hispo_pl.callbacks.AnchorExtension
    - class_path: hispo_pl.callbacks.DirichletEvaluation
      init_args: {n_candidates: 8, n_batches: 1, survivors: null}
    - class_path: hispo_pl.callbacks.SubspacePruning
    - class_path: hispo_pl.callbacks.RolloutEvaluation
      init_args: {episodes: 2}
"""


def stream_dir(save_dir: Path) -> Path:
    return save_dir / "pointmaze-1" / "seed0"


def cli_source(args: list[str], prelude: str = "") -> str:
    """Python source that runs ``hispo-pl`` with ``args`` after ``prelude`` (patches)."""
    return f"{prelude}\nimport sys\nfrom hispo_pl.cli import main\nsys.exit(main({args!r}))\n"


def spawn(source: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(
        [sys.executable, "-c", source],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )


def wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"finished before {path.name} appeared:\n{out[-2000:]}\n{err[-3000:]}")
        if time.monotonic() > end:
            proc.kill()
            pytest.fail(f"{path} did not appear")
        time.sleep(0.02)


SLOW_STEPS = """
import time
from hispo_pl.modules.hbc import GoalConditionedBC
_step = GoalConditionedBC.training_step
def _slow(self, *args):
    time.sleep(0.05)
    return _step(self, *args)
GoalConditionedBC.training_step = _slow
"""
