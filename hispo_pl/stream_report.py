"""What a stream tells its loggers: after each task, the success on every task seen so far
(forgetting curves) and a picture of its rollouts; at the end, the metrics of
:data:`~hispo_pl.metrics.METRICS` as scalars and as the HParams tab's metrics, the success
matrix as a heatmap and a table, the anchor weights per task and the decisions.

Every stream-level value is logged at step = number of tasks trained (1 after the first task),
through every logger of the trainer (TensorBoard, CSV, MLflow, W&B...); figures, text and the
Custom Scalars layout go to the loggers that can show them (TensorBoard). Success values are in
% as the console and the tables print them (``results.json`` keeps fractions); MEM is a ratio.
"""

from __future__ import annotations

from collections.abc import Sequence

from lightning.pytorch.loggers import Logger, TensorBoardLogger
from matplotlib.figure import Figure

from .figures import (
    anchor_weights_figure,
    forgetting_figure,
    simplex_figure,
    success_matrix_figure,
    task_labels,
    task_tag,
)
from .metrics import METRICS
from .results import (
    DECISION_KINDS,
    RULE_LINE,
    RULE_RATIO,
    Decision,
    StreamResults,
    decisions_table,
)


def task_row_metrics(task_index: int, row: Sequence[float]) -> dict[str, float]:
    """After task ``task_index`` (0-based): the success on every task of the stream (a task's
    curve starts with its zero-shot points, then shows what is kept or forgotten) and the mean
    over the tasks trained so far."""
    metrics = {
        f"stream/success/{label}": 100 * s
        for label, s in zip(task_labels(len(row)), row, strict=True)
    }
    seen = row[: task_index + 1]
    metrics["stream/success/mean_seen"] = 100 * sum(seen) / len(seen)
    return metrics


def stream_metrics(results: StreamResults) -> dict[str, float]:
    """``stream/PER`` ... of a finished stream: each metric of
    :data:`~hispo_pl.metrics.METRICS` it has, at its printed scale (success in %, MEM a ratio)."""
    return {
        f"stream/{m.name}": m.scale * float(results.metrics[m.name])
        for m in METRICS
        if results.metrics.get(m.name) is not None
    }


def _mem_logged(results: StreamResults) -> bool:
    """Whether the last task's end logged ``stream/MEM`` (a run that measured MEM per task)."""
    return bool(results.mem_per_task) and results.mem_per_task[-1] is not None


def anchor_metrics(results: StreamResults) -> dict[str, float]:
    """``anchors/<subspace>/count`` of a finished stream: the HParams tab's anchor columns."""
    return {f"anchors/{k}/count": float(v) for k, v in (results.anchors or {}).items()}


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


def run_decisions_markdown(decisions: Sequence[Decision]) -> str:
    """A table per kind of decision the run took (:func:`~hispo_pl.results.decisions_table`):
    one row per task and subspace, with what its rule compared and the anchors after."""
    tables = [decisions_table(kind, [((), decisions)]) for kind in DECISION_KINDS]
    return "\n\n".join("\n".join(lines) for lines in tables if lines)


def anchors_markdown(decisions: Sequence[Decision]) -> str:
    """The anchor count of each subspace after each task, with the decision that set it (a
    few points a line chart hardly shows)."""
    subspaces = list(dict.fromkeys(d.subspace for d in decisions))
    last = {(d.task, d.subspace): d for d in decisions}
    lines = ["| after | " + " | ".join(subspaces) + " |", "|---|" + "---:|" * len(subspaces)]
    for task in sorted({t for t, _ in last}):
        cells = [
            f"{last[task, s].anchors} ({last[task, s].decision})" if (task, s) in last else ""
            for s in subspaces
        ]
        lines.append(f"| {task_tag(task)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plain_hparams(settings: dict) -> dict[str, float | int | str | bool]:
    """Run settings as values the HParams tab accepts (anything else as text)."""
    return {
        k: v if isinstance(v, bool | int | float | str) else str(v) for k, v in settings.items()
    }


# (HParams name, the flat setting it reads): the choices that tell runs apart
CHOSEN_SETTINGS = (
    ("seed", "seed_everything"),
    ("preset", "preset"),
    ("steps_per_task", "trainer.max_steps"),
    ("batch_size", "data.batch_size"),
    ("lr", "model.init_args.optim.lr"),
)


def nested_settings(settings: dict) -> dict:
    """A run's flat settings (:func:`~hispo_pl.run_checks.run_fingerprint`) nested again as
    a configuration, its callbacks a list (in the order of their keys)."""
    config: dict = {}
    callbacks: dict[str, dict] = {}
    head = "trainer.callbacks["
    for key, value in settings.items():
        node, rest = config, key
        if key.startswith(head) and "]." in key:
            label, rest = key[len(head) :].split("].", 1)
            node = callbacks.setdefault(label, {})
        *parents, last = rest.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[last] = value
    if callbacks:
        config.setdefault("trainer", {})["callbacks"] = list(callbacks.values())
    return config


def chosen_hparams(settings: dict, decisions: Sequence[Decision] = ()) -> dict:
    """The HParams tab's columns: the settings a user chooses between runs (the method by its
    display name, stream, seed, steps per task, batch, learning rate, widths, evaluation
    episodes) and each subspace's pruning tolerance as applied (the decisions' ``eps``, so a
    family default shows its value, not ``None``). Lightning's defaults stay out; the whole
    configuration is in the run directory's ``task_XX.config.yaml``."""
    from .callbacks import RolloutEvaluation
    from .methods import config_callbacks, method_name

    config = nested_settings(settings)
    chosen: dict = {}
    name = method_name(config)
    if name is not None:
        chosen["method"] = name
    stream = settings.get("data.stream")
    if stream:
        chosen["stream"] = stream if isinstance(stream, str) else " -> ".join(map(str, stream))
    for column, key in CHOSEN_SETTINGS:
        if settings.get(key) is not None:
            chosen[column] = settings[key]
    for cls, callback in config_callbacks(config):
        episodes = (callback.get("init_args") or {}).get("episodes")
        if cls is not None and issubclass(cls, RolloutEvaluation) and episodes is not None:
            chosen.setdefault("episodes", episodes)
    model = (config.get("model") or {}).get("init_args") or {}
    for key, value in {**model, **(model.get("backbone") or {})}.items():
        if ("hidden" in key or "width" in key) and value is not None:
            chosen[key] = value
    for d in decisions:
        if d.tolerance is not None:
            chosen[f"eps_{d.subspace}"] = d.tolerance
    return plain_hparams(chosen)


def custom_scalars_layout(subspaces: Sequence[str] = (), n_tasks: int = 0) -> dict:
    """TensorBoard's Custom Scalars tab, ``{category: {chart title: tags}}``: one chart per
    task with its forgetting curve (the runs of a folder, each in its own colour, side by side
    for that task), the mean over the tasks trained, the anchor counts, and per subspace the
    pruning rule, ``L_prev / L_curr`` against the line ``1 + eps`` (the new anchor is pruned
    at or below it). :func:`custom_scalars_summary` draws each tag so that its every value
    is on the chart's axis."""
    forgetting = {
        f"{tag}: success on {tag} after each task trained (%)": [f"stream/success/{tag}"]
        for tag in task_labels(n_tasks)
    }
    stream = {"mean success on the tasks trained so far (%)": ["stream/success/mean_seen"]}
    if subspaces:
        stream["anchors per subspace after each task"] = [
            f"anchors/{name}/count" for name in subspaces
        ]
    layout = (
        {"forgetting curves": forgetting, "stream": stream} if forgetting else {"stream": stream}
    )
    if subspaces:
        layout["pruning rule"] = {
            f"{name}: L_prev / L_curr against 1 + eps (pruned at or below the line)": [
                f"search/{name}/{RULE_RATIO}",
                f"search/{name}/{RULE_LINE}",
            ]
            for name in subspaces
        }
    return layout


def custom_scalars_summary(layout: dict):
    """The Custom Scalars layout as a summary, each tag a margin chart's series whose band is
    the value itself (no band drawn). The tab scales a multiline chart's axis after leaving
    out its extreme 5 % ("ignore outliers", on by default), which with a few points per task
    leaves out the very values a chart is for (a chart of two points shows neither); a
    margin series gives it each raw value twice more, so the extremes stay on the axis."""
    from tensorboard.compat.proto.summary_pb2 import Summary, SummaryMetadata
    from tensorboard.compat.proto.tensor_pb2 import TensorProto
    from tensorboard.compat.proto.tensor_shape_pb2 import TensorShapeProto
    from tensorboard.plugins.custom_scalar import layout_pb2

    series = layout_pb2.MarginChartContent.Series
    categories = [
        layout_pb2.Category(
            title=category,
            chart=[
                layout_pb2.Chart(
                    title=title,
                    margin=layout_pb2.MarginChartContent(
                        series=[series(value=tag, lower=tag, upper=tag) for tag in tags]
                    ),
                )
                for title, tags in charts.items()
            ],
        )
        for category, charts in layout.items()
    ]
    tensor = TensorProto(
        dtype="DT_STRING",
        string_val=[layout_pb2.Layout(category=categories).SerializeToString()],
        tensor_shape=TensorShapeProto(),
    )
    metadata = SummaryMetadata(plugin_data=SummaryMetadata.PluginData(plugin_name="custom_scalars"))
    value = Summary.Value(tag="custom_scalars__config__", tensor=tensor, metadata=metadata)
    return Summary(value=[value])


def write_hparams(
    logger: TensorBoardLogger, hparams: dict, columns: Sequence[str], step: int
) -> None:
    """The HParams tab's entry: ``hparams`` and, as its metric columns, the scalar tags
    ``columns`` (already logged: each column shows its tag's last value). Lightning's
    ``log_hyperparams(params, metrics)`` would log every column again as a scalar."""
    from torch.utils.tensorboard.summary import hparams as hparams_summaries

    logger.log_hyperparams(hparams)  # hparams.yaml; no summary without metrics
    writer = logger.experiment._get_file_writer()  # as Lightning's own log_hyperparams
    for summary in hparams_summaries(hparams, dict.fromkeys(columns, 0.0)):
        writer.add_summary(summary, step)


def log_task_end(
    loggers: Sequence[Logger],
    rows: Sequence[Sequence[float]],
    picture: Figure | None,
    subspaces: Sequence[str] | None = None,
    memory: float | None = None,
) -> None:
    """After the task of ``rows``' last row (R so far, one row per task trained): the
    forgetting curves' next point, the memory so far (``stream/MEM``, when measured), the
    rollout picture and, for TensorBoard, the forgetting curves drawn as they are (no
    smoothing, one colour per task). With ``subspaces`` (the names the method decides on; []
    for none), TensorBoard also gets the Custom Scalars layout (give them once: the tab reads
    one layout per run)."""
    task_index = len(rows) - 1
    step = task_index + 1
    metrics = task_row_metrics(task_index, rows[-1])
    if memory is not None:
        metrics["stream/MEM"] = memory
    for logger in loggers:
        logger.log_metrics(metrics, step=step)
        if not isinstance(logger, TensorBoardLogger):
            continue
        if picture is not None:
            logger.experiment.add_figure(f"rollouts/{task_tag(task_index)}", picture, step)
        logger.experiment.add_figure("stream/forgetting", forgetting_figure(rows), step)
        if subspaces is not None:
            layout = custom_scalars_layout(subspaces, n_tasks=len(rows[-1]))
            logger.experiment._get_file_writer().add_summary(custom_scalars_summary(layout))


def log_stream_end(
    loggers: Sequence[Logger],
    results: StreamResults,
    decisions: Sequence[Decision],
    settings: dict,
) -> None:
    """A finished stream: its metrics (also as the HParams tab's), the success matrix, the
    anchor weights and the decisions."""
    step = len(results.R)
    metrics = stream_metrics(results)
    # MEM after the last task is its task-end point already (log_task_end), not logged twice
    once = {k: v for k, v in metrics.items() if k != "stream/MEM" or not _mem_logged(results)}
    alphas = results.alphas or {}
    hparams = chosen_hparams(settings, decisions)
    for logger in loggers:
        if isinstance(logger, TensorBoardLogger):
            logger.log_metrics(once, step=step)
            write_hparams(logger, hparams, [*metrics, *anchor_metrics(results)], step)
            writer = logger.experiment
            matrix = success_matrix_figure(results.R, results.stream)
            writer.add_figure("stream/success_matrix", matrix, step)
            writer.add_text("stream/success_matrix", success_markdown(results.R), step)
            for subspace, rows in alphas.items():
                writer.add_figure(f"alpha/{subspace}", anchor_weights_figure(rows, subspace), step)
                if rows and len(rows[0]) == 3:
                    writer.add_figure(
                        f"alpha/{subspace}/simplex", simplex_figure(rows, subspace), step
                    )
            if decisions:
                writer.add_text("stream/decisions", run_decisions_markdown(decisions), step)
                writer.add_text("stream/anchors", anchors_markdown(decisions), step)
        else:  # no pictures: the anchor weights as scalars
            logger.log_hyperparams(hparams)
            logger.log_metrics({**once, **alpha_metrics(alphas)}, step=step)
        logger.save()
