"""The set-up the README gives: `make demo` installs what the demo needs and no more, `make
test` adds the tests' extras, torch is pinned by the Makefile (and so by CI) with the CPU wheel
one variable away, and the README's examples name the demo's own run as it is."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()
CPU_WHEELS = "https://download.pytorch.org/whl/cpu"

needs_make = pytest.mark.skipif(shutil.which("make") is None, reason="no make here")


def _planned(target: str, tmp_path: Path, *variables: str) -> list[str]:
    """The commands ``make TARGET`` would run for a fresh virtual environment (``make -n``)."""
    venv = tmp_path / "venv"
    done = subprocess.run(
        ["make", "-n", "-C", str(ROOT), target, f"VENV={venv}", *variables],
        capture_output=True,
        text=True,
        check=True,
    )
    return [line for line in done.stdout.splitlines() if "pip install" in line]


@needs_make
def test_make_demo_installs_the_package_without_the_tests_extras(tmp_path):
    installs = _planned("demo", tmp_path)
    assert any(line.endswith("pip install -q -e .") for line in installs), installs
    assert not any("[dev]" in line for line in installs)


@needs_make
def test_make_test_adds_the_tests_extras(tmp_path):
    installs = _planned("test", tmp_path)
    assert installs[-1].endswith('pip install -q -e ".[dev]"'), installs


@needs_make
def test_torch_is_pinned_and_its_cpu_wheel_is_one_variable_away(tmp_path):
    (torch_line,) = [line for line in _planned("demo", tmp_path) if "torch==" in line]
    assert '"torch==2.13.0"' in torch_line and "--index-url" not in torch_line
    (cpu_line,) = [
        line
        for line in _planned("demo", tmp_path, f"TORCH_INDEX={CPU_WHEELS}")
        if "torch==" in line
    ]
    assert cpu_line.endswith(f'"torch==2.13.0" --index-url {CPU_WHEELS}')
    assert f"make demo TORCH_INDEX={CPU_WHEELS}" in README
    assert f"pip install torch==2.13.0 --index-url {CPU_WHEELS}" in README
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert re.search(r'"torch>=[\d.]+"', pyproject)  # the package's range stays open


def test_ci_runs_the_readmes_test_command():
    commands = [
        line
        for line in (ROOT / ".ci/run").read_text().splitlines()
        if line.strip() and not line.startswith(("#", "set ", "cd "))
    ]
    assert commands == ["make test"]
    setup = README.split("## Set-up", 1)[1].split("\n## ", 1)[0]
    assert re.search(r"^make test\s+#", setup, re.M)


def test_the_readme_says_how_long_each_make_target_takes():
    setup = " ".join(README.split("## Set-up", 1)[1].split("\n## ", 1)[0].split())
    for target in ("make demo", "make test"):
        said = setup.split(f"`{target}` installs" if target == "make demo" else f"`{target}` adds")
        assert len(said) == 2, target
        assert re.search(r"about \d+ minutes the first time", said[1][:300]), target
        assert re.search(r"about \d+ minutes on 2 cores", said[1][:500]), target


def test_the_readmes_render_of_the_demo_names_the_demos_task_2():
    """The demo's task 2 is a variant of the maze: its policy is drawn on that variant."""
    stream = yaml.safe_load((ROOT / "configs/demo.yaml").read_text())["data"]["stream"]
    task_2 = re.sub(r"\[\d+\]$", "", stream[1])
    renders = re.findall(r"hispo-pl render (\S+) --ckpt runs/demo/seed0/task_02\.ckpt", README)
    assert renders and set(renders) == {task_2}, renders
