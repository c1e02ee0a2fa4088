"""The checkout's commit, recorded in each run's ``run.json`` when the run is launched, so that
a run's manifest row needs nothing but its own files: the commit of ``HEAD`` and ``+dirty``
when tracked files differ from it (a run meant for committing is launched from a clean tree)."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(ROOT), *args], capture_output=True, text=True, timeout=10
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def checkout_commit() -> dict:
    """``{"commit": HASH}`` (``HASH+dirty`` with uncommitted changes to tracked files; None
    outside a checkout): a recorder for ``hispo_pl.benchmark.plan.CODE_RECORDERS``."""
    commit = _git("rev-parse", "HEAD")
    if commit and _git("status", "--porcelain", "--untracked-files=no"):
        commit += "+dirty"
    return {"commit": commit}
