"""What a stream tells its loggers: after each task, the success on every task seen so far
(forgetting curves) and a picture of its rollouts; at the end, PER, BWT, FWT and MEM as
scalars and as the HParams tab's metrics, the success matrix as a heatmap and a table, the
anchor weights per task and the decisions.

Every stream-level value is logged at step = number of tasks trained (1 after the first task),
through every logger of the trainer (TensorBoard, CSV, MLflow, W&B...); figures and text go to
the loggers that can show them (TensorBoard).
"""

from __future__ import annotations

from collections.abc import Sequence

from lightning.pytorch.loggers import Logger, TensorBoardLogger
from matplotlib.figure import Figure

from .figures import (
    anchor_weights_figure,
    simplex_figure,
    success_matrix_figure,
    task_labels,
    task_tag,
)

STREAM_METRICS = ("PER", "BWT", "FWT", "MEM")


def task_row_metrics(task_index: int, row: Sequence[float]) -> dict[str, float]:
    """After task ``task_index`` (0-based): the success on every task of the stream (a task's
    curve starts with its zero-shot points, then shows what is kept or forgotten) and the mean
    over the tasks trained so far."""
    metrics = {
        f"stream/success/{label}": s for label, s in zip(task_labels(len(row)), row, strict=True)
    }
    seen = row[: task_index + 1]
    metrics["stream/success/mean_seen"] = sum(seen) / len(seen)
    return metrics


def stream_metrics(results: dict) -> dict[str, float]:
    """``stream/PER`` ... of a finished stream's results (those it has)."""
    return {f"stream/{k}": float(results[k]) for k in STREAM_METRICS if results.get(k) is not None}


def alpha_metrics(alphas: dict[str, Sequence[Sequence[float]]]) -> dict[str, float]:
    """Each task's weight on each anchor, per subspace: ``alpha/low/T02/anchor_1``."""
    return {
        f"alpha/{subspace}/{label}/anchor_{j + 1}": float(w)
        for subspace, rows in alphas.items()
        for label, row in zip(task_labels(len(rows)), rows, strict=True)
        for j, w in enumerate(row)
    }


def success_markdown(R: Sequence[Sequence[float | None]]) -> str:
    """R × 100 as a markdown table (rows: after training task i)."""
    labels = task_labels(len(R))
    lines = ["| after | " + " | ".join(labels) + " |", "|---|" + "---:|" * len(labels)]
    for label, row in zip(labels, R, strict=True):
        cells = ["" if v is None else f"{100 * v:.0f}" for v in row]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def decisions_markdown(decisions: Sequence[dict]) -> str:
    """One row per task and subspace: decision, the losses the rule compared, anchors after.
    (A zero-shot record's ``eps`` is the PAC test's, per subspace: not a pruning tolerance.)"""
    lines = [
        "| task | subspace | decision | L_prev | L_curr | L_prev / L_curr | 1 + ε | anchors |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for d in decisions:
        prev, curr = d.get("l_prev"), d.get("l_curr")
        ratio = f"{prev / curr:.3f}" if prev is not None and curr else ""
        eps = f"{1 + d['eps']:.2f}" if isinstance(d.get("eps"), int | float) else ""
        lines.append(
            f"| {task_tag(d['task'])} | {d['subspace']} | {d['decision']} | "
            f"{'' if prev is None else f'{prev:.4f}'} | {'' if curr is None else f'{curr:.4f}'} | "
            f"{ratio} | {eps} | {d.get('anchors', '')} |"
        )
    return "\n".join(lines)


def plain_hparams(settings: dict) -> dict[str, float | int | str | bool]:
    """Run settings as values the HParams tab accepts (anything else as text)."""
    return {
        k: v if isinstance(v, bool | int | float | str) else str(v) for k, v in settings.items()
    }


def log_task_end(
    loggers: Sequence[Logger], task_index: int, row: Sequence[float], picture: Figure | None
) -> None:
    """After task ``task_index``: the forgetting curves' next point, and the rollout picture."""
    step = task_index + 1
    metrics = task_row_metrics(task_index, row)
    for logger in loggers:
        logger.log_metrics(metrics, step=step)
        if picture is not None and isinstance(logger, TensorBoardLogger):
            logger.experiment.add_figure(f"rollouts/{task_tag(task_index)}", picture, step)


def log_stream_end(
    loggers: Sequence[Logger], results: dict, decisions: Sequence[dict], settings: dict
) -> None:
    """A finished stream: its metrics (also as the HParams tab's), the success matrix, the
    anchor weights and the decisions."""
    step = len(results["R"])
    metrics = stream_metrics(results)
    alphas = results.get("alphas") or {}
    hparams = plain_hparams(settings)
    for logger in loggers:
        logger.log_metrics(alpha_metrics(alphas), step=step)
        if isinstance(logger, TensorBoardLogger):
            logger.log_hyperparams(hparams, metrics=metrics, step=step)  # writes the scalars too
            writer = logger.experiment
            writer.add_figure("stream/success_matrix", success_matrix_figure(results["R"]), step)
            writer.add_text("stream/success_matrix", success_markdown(results["R"]), step)
            for subspace, rows in alphas.items():
                writer.add_figure(f"alpha/{subspace}", anchor_weights_figure(rows, subspace), step)
                if rows and len(rows[0]) == 3:
                    writer.add_figure(
                        f"alpha/{subspace}/simplex", simplex_figure(rows, subspace), step
                    )
            if decisions:
                writer.add_text("stream/decisions", decisions_markdown(decisions), step)
        else:
            logger.log_hyperparams(hparams)
            logger.log_metrics(metrics, step=step)
        logger.save()
