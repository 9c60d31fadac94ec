"""The method sees no ground truth: template creation and registration read the capture only.

(a) no module of ``gpja.register`` (nor the CLI's template and register commands) imports the ground-truth
    reader or the synthetic generator;
(b) ``gpja template``, ``gpja register`` and ``gpja order`` (which expression a registration starts from) have no
    ground-truth option;
(c) at run time, on a tiny synthetic subject whose ground truth sits beside its images and scans, neither
    command opens or lists a file of the ground-truth folder (every ``open`` and directory listing of the
    process is recorded through a ``sys.addaudithook`` hook), and the template's lighting is estimated;
(d) the workflow's template and registration jobs declare no ground-truth input and pass no ground-truth
    option (a Snakemake dry run of the CI config).
Only the metrics and the figures read the synthetic ground truth.
"""
from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import gpja.cli
from gpja.cli import build_parser, main
from tests.test_layers import imported_modules, package_imports, within

ORACLES = ("gpja.data.ground_truth", "gpja.data.synthetic")
#: The CLI functions on the method's path (the template and registration commands and what they share).
METHOD_COMMANDS = ("cmd_template", "cmd_register", "_load_for_registration", "cmd_order")
GROUND_TRUTH_WORDS = re.compile(r"ground.?truth|\bgt\b|oracle", re.I)


def test_registration_modules_import_no_ground_truth():
    bad = [f"{module} imports {target} (line {line})" for module, targets in package_imports().items()
           if within(module, "gpja.register") for target, line in targets if within(target, ORACLES)]
    assert not bad, "\n".join(bad)


def test_the_walk_would_see_a_ground_truth_import(tmp_path, monkeypatch):
    """The check can fail: a function-level import of the reader in a registration module is found."""
    import tests.test_layers

    probe = tmp_path / "gpja" / "register" / "probe.py"
    probe.parent.mkdir(parents=True)
    probe.write_text("def f():\n    from gpja.data.ground_truth import lighting_for\n")
    monkeypatch.setattr(tests.test_layers, "PACKAGE_DIR", tmp_path / "gpja")
    assert ("gpja.data.ground_truth", 2) in imported_modules(probe)


def test_the_method_commands_import_no_ground_truth():
    tree = ast.parse(Path(gpja.cli.__file__).read_text(encoding="utf-8"))
    functions = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef)}
    assert set(METHOD_COMMANDS) <= set(functions)
    for name in METHOD_COMMANDS:
        for node in ast.walk(functions[name]):
            if isinstance(node, ast.ImportFrom):
                assert not within(node.module or "", ORACLES), f"{name} imports {node.module}"
            elif isinstance(node, ast.Attribute) or isinstance(node, ast.Name):
                text = node.attr if isinstance(node, ast.Attribute) else node.id
                assert not GROUND_TRUTH_WORDS.search(text), f"{name} uses {text}"


@pytest.mark.parametrize("command", ["template", "register", "order"])
def test_method_commands_have_no_ground_truth_option(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    assert "--scans-root" in text and "--output" in text  # the help was printed
    assert not GROUND_TRUTH_WORDS.search(text), text
    sub = build_parser()._subparsers._group_actions[0].choices[command]
    options = [o for action in sub._actions for o in action.option_strings]
    assert not [o for o in options if GROUND_TRUTH_WORDS.search(o)], options
    assert "--ground-truth-root" in build_parser()._subparsers._group_actions[0].choices["metrics"].format_help()


# --- (c) at run time -----------------------------------------------------------------------------------------

class OpenRecorder:
    """Every path the process opens or lists while ``active`` (audit events ``open``, ``os.listdir``,
    ``os.scandir``; hooks cannot be removed, so one recorder is installed once and switched)."""

    active: list[str] | None = None

    @classmethod
    def hook(cls, event: str, args) -> None:
        if cls.active is None or event not in ("open", "os.listdir", "os.scandir"):
            return
        path = args[0] if args else None
        if isinstance(path, (str, bytes, os.PathLike)):
            cls.active.append(os.path.abspath(os.fsdecode(path)))


sys.addaudithook(OpenRecorder.hook)


@pytest.fixture(scope="module")
def tiny_subject(tmp_path_factory):
    """A 2-expression synthetic subject at 64 px (4 views) in the workflow's layout: images/, scans/, ground_truth/."""
    from gpja.data.synthetic import SynthConfig, subject_seed_index, synthesize_subject

    root = tmp_path_factory.mktemp("no_oracle")
    cfg = SynthConfig(seed=3, image_size=64, n_views=4, scan_voxel_mm=1.5, render_voxel_mm=1.5, supersample=1,
                      expressions=("3_mouth_stretch", "1_neutral"), raw_variant=False)
    synthesize_subject("S01", subject_seed_index("S01"), cfg, root / "images", root / "scans", root / "ground_truth",
                       None, root / "contact_sheet.png", progress=lambda m: None)
    return root


def run_recorded(argv: list[str]) -> list[str]:
    OpenRecorder.active = []
    try:
        assert main(argv) == 0
        return OpenRecorder.active
    finally:
        OpenRecorder.active = None


@pytest.mark.slow
def test_template_and_registration_open_no_ground_truth_file(tiny_subject, tmp_path):
    root = tiny_subject
    truth = str((root / "ground_truth").resolve())
    assert any((root / "ground_truth" / "S01").iterdir())
    data = ["--subject", "S01", "--images-root", str(root / "images"), "--scans-root", str(root / "scans"),
            "--cache-dir", str(tmp_path / "cache"), "--backend", "cpu"]
    template_settings = {"bust_edge_mm": 12.0, "lambdas": [100.0], "iterations": [4], "texture_size": 64, "faces": 1500}
    opened = run_recorded(["--threads", "1", "template", *data, "--expression", "3_mouth_stretch",
                           "--targets", str(tmp_path / "t3.npz"), "--settings", json.dumps(template_settings),
                           "--output-dir", str(tmp_path / "template")])
    lighting = json.loads((tmp_path / "template" / "lighting.json").read_text())
    assert lighting["source"] == "estimated" and len(lighting["sh"]) == 9
    opened += run_recorded(["--threads", "1", "register", *data, "--expression", "1_neutral",
                            "--targets", str(tmp_path / "t1.npz"), "--settings", '{"lambdas": [50], "iterations": [3]}',
                            "--template-dir", str(tmp_path / "template"), "--output", str(tmp_path / "r" / "1.obj")])
    assert (tmp_path / "r" / "1.obj").is_file()
    opened += run_recorded(["--threads", "1", "order", "--subject", "S01", "--scans-root", str(root / "scans"),
                            "--expressions", "1_neutral", "--output", str(tmp_path / "order.json")])
    assert json.loads((tmp_path / "order.json").read_text())["parent"] == {"3_mouth_stretch": None,
                                                                          "1_neutral": "3_mouth_stretch"}
    assert any(p.startswith(str((root / "images").resolve())) for p in opened)  # the recorder sees the data reads
    leaked = sorted({p for p in opened if os.path.realpath(p).startswith(truth)})
    assert not leaked, f"the method opened ground truth: {leaked}"


# --- (d) the workflow ----------------------------------------------------------------------------------------

def test_template_and_registration_jobs_declare_no_ground_truth(tmp_path):
    from tests.test_project import SNAKEMAKE, copy_workflow

    work = copy_workflow(tmp_path)
    cfg = yaml.safe_load((work / "config/ci.yaml").read_text())
    gt_root = cfg["data"]["ground_truth_root"]
    targets = [f"results/{cfg['dataset']}/S01/gpja/1_neutral.obj",
               f"results/{cfg['dataset']}/S01/gpja/metrics/1_neutral.json"]
    out = subprocess.run([*SNAKEMAKE, "-n", "-p", "--cores", "1", "--configfile", "config/ci.yaml", "--", *targets],
                         cwd=work, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    blocks = {}
    for block in re.split(r"\n(?=(?:local)?(?:rule|checkpoint) \w+:)", out.stdout):
        head = re.match(r"(?:local)?(?:rule|checkpoint) (\w+):", block.strip())
        if head:
            blocks[head.group(1)] = block
    assert {"build_template", "register_expression", "registration_order", "compute_metrics"} <= set(blocks)
    for rule in ("build_template", "register_expression", "registration_order"):
        inputs = re.search(r"^\s*input: (.*)$", blocks[rule], re.M).group(1)
        assert gt_root not in inputs and not GROUND_TRUTH_WORDS.search(blocks[rule]), blocks[rule]
    # the metrics do read it (the check above would see it)
    assert gt_root in re.search(r"^\s*input: (.*)$", blocks["compute_metrics"], re.M).group(1)
