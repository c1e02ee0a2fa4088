"""The documentation holds: every hispo-pl command the README shows parses, every relative link
resolves, and every report embedded in docs/results.md is what its committed run files give."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from hispo_pl.cli import main
from lab.embed import EMBED_BEGIN, embed_reports

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _readme_commands() -> list[str]:
    """``hispo-pl`` lines of the README's bash blocks, continuation lines joined."""
    text = (ROOT / "README.md").read_text()
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split("  #")[0].strip()
            if line.startswith("hispo-pl "):
                commands.append(line)
    return commands


def test_readme_shows_commands():
    verbs = {shlex.split(c)[1] for c in _readme_commands()}
    assert {"fit", "data", "benchmark", "evaluate", "render"} <= verbs


@pytest.mark.parametrize("command", _readme_commands())
def test_every_readme_command_parses(command, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    args = shlex.split(command)[1:]
    args += ["--print_config"] if args[0] == "fit" else ["--help"]
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code in (0, None), capsys.readouterr().err


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    for target in LINK.findall(page.read_text()):
        if "://" in target or target.startswith("#") or target.startswith("mailto:"):
            continue
        path = (page.parent / target.split("#")[0]).resolve()
        assert path.exists(), f"{page.relative_to(ROOT)} links to a missing {target}"


REPORT_PAGES = [p for p in PAGES if EMBED_BEGIN in p.read_text()]


def test_results_page_embeds_reports():
    assert ROOT / "docs" / "results.md" in REPORT_PAGES


@pytest.mark.parametrize("page", REPORT_PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_embedded_reports_equal_their_rebuilt_run_files(page):
    """Exact text: the reports format the committed files' numbers (float64 means and spreads
    of a few values, in a fixed order), which every IEEE 754 machine rounds alike; nothing is
    retrained."""
    name = page.relative_to(ROOT)
    assert embed_reports(page, ROOT) == page.read_text(), (
        f"{name} differs from its run files: rebuild it with\n  python -m lab rebuild-docs {name}"
    )


def test_every_committed_results_folder_is_indexed():
    """docs/results/README.md names every folder under docs/results, so none is a mystery."""
    index = (ROOT / "docs/results/README.md").read_text()
    folders = sorted(p.name for p in (ROOT / "docs/results").iterdir() if p.is_dir())
    assert [f for f in folders if f"`{f}/`" not in index] == []
