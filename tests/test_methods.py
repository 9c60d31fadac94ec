"""gpja.methods: the registry every rule, table and figure reads, its config check, and the generic
`gpja baseline` command that runs any registered baseline."""
from __future__ import annotations

import json

import pytest

from gpja import methods as M
from gpja.cli import main
from gpja.data.source import DataSource
from gpja.errors import InputError

CALLS: list[tuple] = []


def toy_baseline(template_dir, source, subject, expression, output, section, template_expression, progress):
    """A baseline with the one signature every baseline has; it records its call."""
    CALLS.append((template_dir, source, subject, expression, output, section, template_expression))
    progress("toy: done")
    return {"vertices": 4}


def test_registry_names_labels_and_switches():
    assert M.names("gpja") == ["gpja"]
    assert M.names("ablation") == ["gpja-no_normal", "gpja-no_depth", "gpja-no_color", "gpja-no_mask", "gpja-no_flow",
                                   "gpja-no_hold", "gpja-no_untangle", "gpja-no_snap", "gpja-no_gain", "gpja-no_scan_color",
                                   "gpja-no_spread", "gpja-paper"]
    assert M.names("baseline") == ["nicp"]
    assert [M.label(m) for m in ("gpja", "nicp", "gpja-no_mask", "nphm")] == ["GPJA", "NICP", "GPJA w/o mask", "nphm"]
    assert M.method("gpja-no_depth").without == ("depth",) and M.method("gpja").without == ()
    assert M.method("gpja-no_normal").ablation_label == ("w/o L_normal", r"w/o $\mathcal{L}_{normal}$")
    assert M.method("gpja-no_mask").ablation_label == "w/o mask"
    assert M.method("nphm").kind == "imported"
    # the paper's schedule: every constraint on, its own config section, always from the template
    paper = M.method("gpja-paper")
    assert paper.without == () and paper.schedule == "paper" and paper.ablation_label == "GPJA (paper schedule)"
    assert not paper.follows_start and M.method("gpja").follows_start and M.method("gpja-no_depth").follows_start
    assert not M.method("nicp").follows_start
    no_flow = M.method("gpja-no_flow")  # the warm-up instead of the flow stage: its own section, GPJA's start
    assert no_flow.without == () and no_flow.schedule == "no_flow" and no_flow.follows_start
    # GPJA's own section with the hold off: only the override differs
    registration = {"gpja": {"lambdas": [1.0], "hold_tangential": 0.01, "hold_gap_mm": [0.5, 2.0]}, "paper": {"lambdas": [2.0]}}
    no_hold = M.method("gpja-no_hold")
    assert no_hold.follows_start and no_hold.ablation_label == "GPJA w/o hold"
    assert no_hold.schedule_settings(registration) == {"lambdas": [1.0], "hold_tangential": 0.0, "hold_gap_mm": [0.5, 2.0]}
    # GPJA with the colour counted beyond the scan too: the limit off, nothing else
    no_scan_color = M.method("gpja-no_scan_color")
    assert no_scan_color.follows_start and no_scan_color.without == ()
    assert no_scan_color.schedule_settings({"gpja": {"lambdas": [1.0], "color_scan_px": 3}}) == {
        "lambdas": [1.0], "color_scan_px": None}
    assert registration["gpja"]["hold_tangential"] == 0.01  # the config is not changed
    assert M.method("gpja").schedule_settings(registration) == registration["gpja"]
    assert paper.schedule_settings(registration) == {"lambdas": [2.0]}


@pytest.mark.parametrize("change, key", [
    (lambda c: c["registration"]["ablations"].update(variants=["gpja-no_light"]), "registration.ablations.variants"),
    (lambda c: c["baselines"].update(icp={"enabled": True}), "baselines.icp"),
    (lambda c: c["baselines"].update(external=[{"name": "gpja", "pattern": "x"}]), "baselines.external"),
    (lambda c: c["baselines"].update(external=[{"name": "tu", "pattern": "x"}, {"name": "tu", "pattern": "y"}]),
     "baselines.external"),
    (lambda c: c["registration"]["ablations"].update(variants=["gpja-paper"]), "registration.paper"),
], ids=["ablation", "baseline", "imported-taken", "imported-twice", "schedule-section"])
def test_config_method_names_are_checked_against_the_registry(change, key):
    config = {"registration": {"gpja": {}, "ablations": {"variants": ["gpja-no_mask"]}},
              "baselines": {"nicp": {"enabled": True}, "external": [{"name": "tu", "pattern": "x"}]}}
    M.check_config(config)
    change(config)
    with pytest.raises(InputError, match=rf"^{key}: "):
        M.check_config(config)


def test_gpja_baseline_runs_any_registered_baseline(tmp_path, monkeypatch, capsys):
    """Adding a baseline is one module plus one METHODS entry: `gpja baseline` finds it by name."""
    monkeypatch.setitem(M.METHODS, "toy", M.Method("toy", "Toy", "baseline", entry="tests.test_methods:toy_baseline"))
    CALLS.clear()
    section = {"enabled": True, "landmarks": "{subject}/{expression}.txt"}
    argv = ["baseline", "--method", "toy", "--subject", "S01", "--expression", "1_neutral",
            "--scans-root", str(tmp_path / "scans"), "--template-dir", str(tmp_path / "template"),
            "--template-expression", "3_mouth_stretch", "--section", json.dumps(section),
            "--output", str(tmp_path / "toy" / "1_neutral.obj")]
    assert main(argv) == 0
    (call,) = CALLS
    assert call == (str(tmp_path / "template"), DataSource(scans_root=tmp_path / "scans"), "S01", "1_neutral",
                    str(tmp_path / "toy" / "1_neutral.obj"), section, "3_mouth_stretch")
    assert "toy: done" in capsys.readouterr().out
    assert main([*argv[:2], "gpja", *argv[3:]]) == 2
    assert "--method: 'gpja' is not a baseline; registered: nicp, toy" in capsys.readouterr().err
    assert main([*argv[:-4], "--section", "[1]", *argv[-2:]]) == 2
    assert "--section: expected a JSON object" in capsys.readouterr().err
