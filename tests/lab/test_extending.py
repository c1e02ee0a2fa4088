"""docs/extending.md runs as written: its files become a package ``mypkg`` in a temp dir (on
``sys.path``, as ``PYTHONPATH=.`` puts it), then each section's Python blocks and
``hispo-pl`` commands run in order, with tiny budgets appended to the commands (few steps,
small batches, two evaluation episodes, the tiny PointMaze data)."""

from __future__ import annotations

import ast
import json
import re
import runpy
import shlex
import shutil
import sys
from pathlib import Path

import pytest
import torch
import yaml
from helpers import TINY_STREAM

from hispo_pl.cli import main
from hispo_pl.config import BackboneConfig
from hispo_pl.tasks import parse_task

ROOT = Path(__file__).resolve().parents[2]
GUIDE = ROOT / "docs" / "extending.md"
BLOCK = re.compile(r"^```(\w+)(?: (\S+))?\n(.*?)^```", flags=re.S | re.M)


def _sections() -> dict[str, list[tuple[str, str | None, str]]]:
    """The guide's code blocks (language, file it names or None, text) per ``## (x)`` section
    (``""`` for the blocks before the first)."""
    sections: dict[str, list] = {}
    for part in re.split(r"^## ", GUIDE.read_text(), flags=re.M):
        key = part[:3] if part.startswith("(") else ""
        blocks = [(lang, target or None, text) for lang, target, text in BLOCK.findall(part)]
        sections.setdefault(key, []).extend(blocks)
    return sections


SECTIONS = _sections()
FILES = {
    target: text
    for blocks in SECTIONS.values()
    for lang, target, text in blocks
    if target and lang in ("python", "yaml")
}


@pytest.fixture
def workdir(tiny_umaze, tmp_path, monkeypatch):
    """A working directory holding the guide's files (``mypkg``, its stream config) and the
    shipped configs, importable as ``PYTHONPATH=.`` makes it."""
    shutil.copytree(ROOT / "configs", tmp_path / "configs")
    for target, text in FILES.items():
        path = tmp_path / target
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in [m for m in sys.modules if m == "mypkg" or m.startswith("mypkg.")]:
        monkeypatch.delitem(sys.modules, name)
    return tmp_path


def _tiny(args: list[str]) -> list[str]:
    """A guide command's arguments with tiny budgets: a stream's tasks at a few episodes of
    the tiny U-maze data (pointmaze-1's mazes replaced by TINY_STREAM), single tasks on 5
    steps."""
    extra = ["--trainer.max_steps", "5", "--data.batch_size", "64"]
    extra += [
        "--trainer.callbacks.init_args.episodes",
        "2",
        "--trainer.enable_progress_bar",
        "false",
    ]
    configs = [args[i + 1] for i, a in enumerate(args) if a == "--config"]
    stream = next((c for c in configs if "/streams/" in c), None)
    if stream is not None:
        tasks = yaml.safe_load(Path(stream).read_text())["data"]["stream"]
        if isinstance(tasks, str):
            tasks = TINY_STREAM
        tiny = [parse_task(t) for t in tasks]
        tiny = [f"{t.family}-{t.maze}-{t.variant}[3]" for t in tiny]
        extra += ["--data.stream", json.dumps(tiny)]
    else:
        extra += ["--trainer.callbacks.init_args.eval_every", "0"]
    if any("methods/hispo" in c for c in configs):
        extra += ["--search_candidates", "4", "--search_batches", "1"]
    return args + extra


def _run(section: str, capsys) -> str:
    """Run a section's blocks in order; the console output of its commands."""
    out = []
    for lang, target, text in SECTIONS[section]:
        if lang == "python" and target is None:
            script = Path("snippet.py")
            script.write_text(text)
            runpy.run_path(str(script), run_name="__main__")
        elif lang == "bash":
            for line in text.replace("\\\n", " ").splitlines():
                words = [w for w in shlex.split(line) if not w.startswith("PYTHONPATH=")]
                if words[:1] == ["hispo-pl"]:
                    assert main(_tiny(words[1:])) == 0, capsys.readouterr().err
                    out.append(capsys.readouterr().out)
    return "".join(out)


def test_the_guide_has_every_recipe():
    assert {"(a)", "(b)", "(c)", "(d)"} <= set(SECTIONS)
    assert all(
        any(lang == "python" and not target for lang, target, _ in SECTIONS[s])
        for s in ("(a)", "(c)")
    )
    assert {"mypkg/__init__.py", "mypkg/method.py", "mypkg/logger.py"} <= set(FILES)
    recipes = ["(a)", "(b)", "(c)", "(d)"]
    assert all(any(lang == "bash" for lang, _, _ in SECTIONS[s]) for s in recipes)


def _private_names(source: str) -> list[str]:
    """Attributes of the form ``x._name`` (dunders aside) that ``source`` reads or writes."""
    return [
        node.attr
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Attribute)
        and node.attr.startswith("_")
        and not (node.attr.startswith("__") and node.attr.endswith("__"))
    ]


def test_the_guide_s_code_touches_no_private_name():
    assert _private_names("m._started = 1; super().__init__()") == ["_started"]
    for target, text in FILES.items():
        if target.endswith(".py"):
            assert _private_names(text) == [], target
    for section in SECTIONS.values():
        for lang, target, text in section:
            if lang == "python" and target is None:
                assert _private_names(text) == []


def test_the_method_s_growth_hook_makes_each_task_s_network(workdir):
    """``next_network`` is what a task's network starts from: the mean of the earlier ones."""
    from mypkg import MeanStart

    m = MeanStart(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16), keep="all")
    for k in range(3):
        m.task_index = k
        m.start_task(k)
        if k == 2:
            pairs = zip(m.nets[0].parameters(), m.nets[1].parameters(), strict=True)
            expected = [torch.stack(pair).mean(0) for pair in pairs]
            for got, want in zip(m.nets[2].parameters(), expected, strict=True):
                torch.testing.assert_close(got, want)
        with torch.no_grad():
            for p in m.training_network.parameters():
                p.add_(0.1 * (k + 1))
        m.finish_task(k)
    assert (len(m.nets), m.n_tasks, m.started_task) == (3, 3, 2)
    m.start_task(2)  # a second start of the same task does not grow
    assert len(m.nets) == 3


def test_a_method_from_a_separate_package_runs_a_stream(workdir, capsys):
    out = _run("(a)", capsys)
    run = workdir / "runs" / "pointmaze-1" / "seed0"
    results = json.loads((run / "results.json").read_text())
    assert len(results["R"]) == 2 and results["PER"] is not None
    config = yaml.safe_load((run / "task_02.config.yaml").read_text())
    assert config["model"]["class_path"] == "mypkg.MeanStart"
    assert "task 2/2" in out


def test_a_stream_of_your_own_runs_from_its_config(workdir, capsys):
    _run("(b)", capsys)
    results = json.loads((workdir / "runs" / "my-stream" / "seed0" / "results.json").read_text())
    assert [parse_task(t).variant for t in results["stream"]] == ["N", "IA", "PO"]


def test_your_own_minari_dataset_trains_a_task_and_is_recorded(workdir, capsys):
    out = _run("(c)", capsys)
    result = json.loads(next((workdir / "runs").rglob("result.json")).read_text())
    assert (result["dataset"], result["dataset_episodes"]) == ("mydata/umaze-v0", 12)
    assert "from mydata/umaze-v0 (12 episodes)" in out and "[500]" not in out


def test_a_logger_of_your_own_gets_the_stream_s_values(workdir, capsys):
    _run("(d)", capsys)
    run = workdir / "runs" / "pm1-jsonl" / "seed0"
    assert (run / "results.json").exists() and (run / "task_02.ckpt").exists()
    logged = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    keys = {k for record in logged for k in record}
    assert {"stream/PER", "stream/success/T02"} <= keys


def test_every_shipped_method_lists_its_evaluation_last():
    from hispo_pl.run_checks import callback_order_problem

    for config in sorted((ROOT / "configs" / "methods").glob("*.yaml")):
        assert callback_order_problem(yaml.safe_load(config.read_text())) is None, config.name


def test_a_task_end_callback_after_the_evaluation_is_refused(tmp_path, capsys):
    """The order the guide asks for is checked: listed after RolloutEvaluation, TaskNetworks
    would record a task's network after its success row was measured."""
    method = yaml.safe_load((ROOT / "configs/methods/ftn.yaml").read_text())
    method["trainer"]["callbacks"].reverse()
    config = tmp_path / "late.yaml"
    config.write_text(yaml.safe_dump(method))
    args = ["fit", "--config", str(ROOT / "configs/streams/pointmaze-1.yaml")]
    assert main([*args, "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert "TaskNetworks after RolloutEvaluation" in err and "list RolloutEvaluation last" in err
