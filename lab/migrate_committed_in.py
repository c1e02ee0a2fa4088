"""One-time migration: a reference run whose ``run.json`` names no commit gets
``committed_in``, the commit that committed its ``results.json`` (``git log``), so that its
manifest row reads from the run's own files. Run once, its result committed, then removed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from hispo_pl.rundir import RunDir

from .manifest import REFERENCE_FOLDERS


def committed_in(path: Path) -> str | None:
    done = subprocess.run(
        ["git", "-C", str(path.parent), "log", "-1", "--format=%h", "--", path.name],
        capture_output=True,
        text=True,
        check=True,
    )
    return done.stdout.strip() or None


def migrate(root: Path) -> int:
    changed = 0
    for name in REFERENCE_FOLDERS:
        for results in sorted((root / name).rglob(RunDir.RESULTS)):
            record_file = results.parent / RunDir.RUN_RECORD
            record = json.loads(record_file.read_text()) if record_file.exists() else {}
            if record.get("commit") or record.get("committed_in"):
                continue
            commit = committed_in(results)
            if commit is None:
                continue
            record["committed_in"] = commit
            record_file.write_text(json.dumps(record, indent=1))
            changed += 1
    return changed


if __name__ == "__main__":
    print(migrate(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/results")), "run.json filled")
