"""``python -m lab config-drift``: a committed run's saved configuration against the command a
grid plans for it today, both parsed by today's ``hispo-pl fit``."""

from __future__ import annotations

import shutil

import yaml
from helpers import ROOT

from hispo_pl.tasks import FAMILIES
from lab import drift
from lab.__main__ import main as lab_main

RUN = ROOT / "docs/results/antmaze-1/hispo/seed0"
LR = "model.init_args.optim.lr"


def test_a_setting_left_to_the_family_reads_as_the_familys_value():
    family = FAMILIES["simpletown"]
    unset = {drift.ANCHOR_INIT: None, drift.PRUNING + "eps_high": None,
             drift.PRUNING + "eps_low": None, drift.PRUNING + "eps": None,
             "data.low_inputs": "family", "data.high_inputs": "family"}  # fmt: skip
    resolved = drift.family_resolved(unset, family)
    assert resolved["data.low_inputs"] == family.low_inputs
    assert resolved["data.high_inputs"] == family.high_inputs
    assert resolved[drift.ANCHOR_INIT] == family.anchor_init
    assert resolved[drift.PRUNING + "eps_high"] == family.pruning_eps["high"]
    assert resolved[drift.PRUNING + "eps_low"] == family.pruning_eps["low"]
    # a subspace the ``eps`` mapping names takes its tolerance from there, not the family's
    named = drift.family_resolved({**unset, drift.PRUNING + "eps.low": 0.2}, family)
    assert named[drift.PRUNING + "eps_low"] is None
    assert named[drift.PRUNING + "eps_high"] == family.pruning_eps["high"]
    # the PAC criterion's tolerances, left unset, are the family's; one given stays
    pac = {drift.TRANSFER + "eps_high": None, drift.TRANSFER + "eps_low": 0.3}
    assert drift.family_resolved(pac, family) == {
        drift.TRANSFER + "eps_high": family.pac_eps["high"],
        drift.TRANSFER + "eps_low": 0.3,
    }
    set_ = {drift.ANCHOR_INIT: "random"}
    assert drift.family_resolved(set_, FAMILIES["antmaze"])[drift.ANCHOR_INIT] == "random"


def test_drift_names_each_differing_setting_both_ways():
    committed = {"a": 1, "b": 2, "gone": 3}
    assert drift.setting_drift(committed, {"a": 1, "b": 4, "new": 5}) == {
        "b": (2, 4),
        "gone": (3, "<absent>"),
        "new": ("<absent>", 5),
    }
    assert drift.setting_drift(committed, dict(committed)) == {}


def _committed_copy(tmp_path, edit=None, run=RUN, cell="antmaze-1/hispo/seed0"):
    """A root holding one committed run as ``cell``, its config edited by ``edit``."""
    target = tmp_path / cell
    shutil.copytree(run, target)
    if edit is not None:
        config = yaml.safe_load((target / "config.yaml").read_text())
        edit(config)
        (target / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    return tmp_path


def test_a_committed_antmaze_run_is_configured_as_the_grid_plans_it_today(tmp_path):
    found = dict(drift.grid_drift("paper", "antmaze-1", _committed_copy(tmp_path)))
    assert found == {"antmaze-1/hispo/seed0": {}}


def test_a_saved_preset_run_is_read_with_the_flags_that_won_over_the_preset(tmp_path):
    """The paper protocol's ε sweep runs HiSPO at ε 0.01, a knob flag over the preset's own
    0.1: the saved configuration holds 0.01 and the preset's name, and reads as the grid's
    command."""
    cell = "pointmaze-1/sweeps/hispo-eps0.01/seed0"
    root = _committed_copy(tmp_path, run=ROOT / "docs/results/paper-protocol" / cell, cell=cell)
    found = dict(drift.grid_drift("paper-protocol", "pointmaze-1", root))
    assert found == {"pointmaze-1/hispo-eps0.01/seed0": {}}


def test_a_setting_changed_since_the_run_is_named_with_both_values(tmp_path, capsys):
    def faster(config):
        config["model"]["init_args"]["optim"]["lr"] = 0.002

    root = _committed_copy(tmp_path, faster)
    today = yaml.safe_load((RUN / "config.yaml").read_text())["model"]["init_args"]["optim"]["lr"]
    found = dict(drift.grid_drift("paper", "antmaze-1", root))
    assert found == {"antmaze-1/hispo/seed0": {LR: (0.002, today)}}
    code = lab_main(["config-drift", "--grid", "paper", "--part", "antmaze-1", "--root", str(root)])
    assert code == 1
    assert f"antmaze-1/hispo/seed0: differs: {LR}: committed 0.002, today {today!r}" in (
        capsys.readouterr().out
    )


def test_a_saved_config_that_today_refuses_is_one_line(tmp_path, capsys):
    def retired(config):
        config["model"]["init_args"]["retired_knob"] = 1

    root = _committed_copy(tmp_path, retired)
    code = lab_main(["config-drift", "--grid", "paper", "--part", "antmaze-1", "--root", str(root)])
    out = capsys.readouterr().out
    assert code == 1
    assert "antmaze-1/hispo/seed0: cannot compare:" in out and "Traceback" not in out


def test_a_saved_config_naming_a_foreign_class_is_refused_unimported(tmp_path, capsys, monkeypatch):
    """Nothing a run file names is imported: a class outside hispo-pl and Lightning is named
    in one line, and its module (importable here, and leaving a mark when imported) is never
    loaded."""
    mark = tmp_path / "imported"
    (tmp_path / "lab_drift_probe.py").write_text(f"open({str(mark)!r}, 'w').close()\n")
    monkeypatch.syspath_prepend(str(tmp_path))

    def foreign(config):
        config["trainer"]["logger"]["class_path"] = "lab_drift_probe.Logger"

    root = _committed_copy(tmp_path / "results", foreign)
    code = lab_main(["config-drift", "--grid", "paper", "--part", "antmaze-1", "--root", str(root)])
    out = capsys.readouterr().out
    assert code == 1 and not mark.exists()
    assert "names classes outside hispo_pl and lightning (lab_drift_probe.Logger)" in out
