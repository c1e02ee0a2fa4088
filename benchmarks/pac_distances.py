"""How far the PAC criterion's best existing point is from each new task's data, along a
finished HiSPO run: what ε the zero-shot test would need, beside the decision the run's
pruning took on that task.

For each task ``k`` after the first, the module is restored from the run's checkpoint of task
``k - 1`` (the state :class:`~hispo_pl.callbacks.ZeroShotTransfer` tests, before any anchor is
added), task ``k``'s datamodule is built as the loop builds it, and the callback's own
measurement (:meth:`~hispo_pl.callbacks.ZeroShotTransfer.best_points`, at the method config's
search settings) gives each policy's distances. The table prints their median and their
``1 - δ`` quantile (the smallest ε the criterion would accept at that δ), and the pruning's
decision and loss ratio on the same task from ``decisions.jsonl``: a criterion that agrees with
the pruning takes a subspace zero-shot where the pruning dropped the new anchor.

    python benchmarks/pac_distances.py RUN_DIR [RUN_DIR ...] [--delta 0.1] [--method hispo-pac] \
        [--json rows.json] [--label RUN_DIR=NAME ...]
    python benchmarks/pac_distances.py --report rows.json    # the table, from the saved rows
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import NamedTuple

import torch
import yaml

from hispo_pl.callbacks import ZeroShotTransfer
from hispo_pl.cli_stream import task_datamodules
from hispo_pl.config_files import config_root
from hispo_pl.fit import run_lightning_cli
from hispo_pl.results import LossDecision
from hispo_pl.rundir import RunDir

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # a script of the checkout: its lab/
from lab.drift import parseable_copy  # noqa: E402


def run_setup(run: RunDir):
    """The run's LightningCLI (its module and first datamodule), as ``hispo-pl fit`` builds
    them from the run's saved configuration (read as ``lab config-drift`` reads one: a class
    outside hispo-pl and Lightning is refused, not imported)."""
    with parseable_copy(run.config_file) as (config, _):
        return run_lightning_cli(["--config", str(config), "--trainer.logger", "false"], run=False)


def criterion(method_config: Path) -> ZeroShotTransfer:
    """The :class:`~hispo_pl.callbacks.ZeroShotTransfer` a method config lists, as it sets it."""
    callbacks = yaml.safe_load(method_config.read_text())["trainer"]["callbacks"]
    found = [c for c in callbacks if str(c["class_path"]).endswith(".ZeroShotTransfer")]
    if not found:
        raise SystemExit(f"{method_config}: lists no ZeroShotTransfer")
    return ZeroShotTransfer(**(found[0].get("init_args") or {}))


class Measured(NamedTuple):
    task: int  # 0-based, the task the criterion tests
    spec: str
    subspace: str
    policy: str
    distances: torch.Tensor


def measure(run: RunDir, transfer: ZeroShotTransfer) -> list[Measured]:
    """Each policy's distances on each task after the first, from the run's checkpoint of the
    task before it."""
    cli = run_setup(run)
    module, first = cli.model, cli.datamodule
    make_datamodule = task_datamodules(first, dict(cli.config["data"]))
    out = []
    for k in range(1, len(first.tasks)):
        module.load_checkpoint_file(run.checkpoint(k - 1))
        datamodule = make_datamodule(first.tasks[k])
        datamodule.prepare_data()
        datamodule.setup("fit")
        for subspace, (_, distances) in transfer.best_points(module, datamodule).items():
            for policy, d in distances.items():
                out.append(Measured(k, first.tasks[k].spec, subspace, policy, d))
    return out


def rows(run: RunDir, measured: list[Measured], delta: float) -> list[dict]:
    """The distances' median and ``1 - δ`` quantile beside the run's pruning on the task."""
    pruning = {
        (d.task, d.subspace): d
        for d in run.decisions()
        if isinstance(d, LossDecision) and d.l_prev is not None
    }
    out = []
    for m in measured:
        q = torch.quantile(m.distances.float(), torch.tensor([0.5, 1 - delta])).tolist()
        decision = pruning.get((m.task, m.subspace))
        out.append(
            {
                "run": str(run.path),
                "task": m.task + 1,
                "spec": m.spec,
                "policy": m.policy,
                "median": q[0],
                "quantile": q[1],
                "pruning": None if decision is None else decision.decision,
                "ratio": None if decision is None else decision.l_prev / decision.l_curr,
            }
        )
    return out


def markdown(rows: list[dict], delta: float) -> str:
    lines = [
        f"| run | task | policy | median d | {1 - delta:.0%} quantile of d | pruning | "
        "L_prev / L_curr |",
        "|---|---|---|---:|---:|---|---:|",
    ]
    for r in rows:
        ratio = "" if r["ratio"] is None else f"{r['ratio']:.2f}"
        lines.append(
            f"| {r['run']} | {r['task']} {r['spec']} | {r['policy']} | {r['median']:.3f} | "
            f"{r['quantile']:.3f} | {r['pruning'] or ''} | {ratio} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", type=Path, help="finished HiSPO run directories")
    parser.add_argument(
        "--method", default="hispo-pac", help="method config with the criterion (name or path)"
    )
    parser.add_argument("--delta", type=float, default=None, help="δ (default: the config's)")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows here")
    parser.add_argument(
        "--label", action="append", default=[], help="RUN_DIR=NAME: how the table names a run"
    )
    parser.add_argument("--report", type=Path, default=None, help="print a saved --json's table")
    args = parser.parse_args(argv)
    if args.report is not None:
        saved = json.loads(args.report.read_text())
        print(markdown(saved["rows"], saved["delta"]))
        return 0
    if not args.runs:
        parser.error("name finished run directories, or --report a saved table")
    labels = dict(label.split("=", 1) for label in args.label)
    torch.set_num_threads(1)
    method = Path(args.method)
    if not method.suffix:
        method = config_root() / "methods" / f"{args.method}.yaml"
    transfer = criterion(method)
    delta = transfer.delta if args.delta is None else args.delta
    table = []
    for path in args.runs:
        run = RunDir(path)
        measured = rows(run, measure(run, transfer), delta)
        table += [{**r, "run": labels.get(str(path), r["run"])} for r in measured]
    print(markdown(table, delta))
    if args.json is not None:
        args.json.write_text(json.dumps({"delta": delta, "rows": table}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
