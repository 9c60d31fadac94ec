"""The ``gpja`` command: every subcommand parses, and bad ``--settings`` stop it before any data is read."""
from __future__ import annotations

import argparse

import pytest

from gpja.cli import build_parser, main

MISSING = "does/not/exist"


def subcommands() -> list[str]:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sorted(action.choices)


def test_the_workflow_steps_are_subcommands():
    assert {"synth", "check-data", "scan-targets", "template", "register", "baseline", "import", "metrics",
            "tables", "figure", "check-regression"} <= set(subcommands())


@pytest.mark.parametrize("command", subcommands())
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code == 0
    assert "usage: gpja" in capsys.readouterr().out


def expression(*extra: str) -> list[str]:
    return ["--subject", "S01", "--expression", "1_neutral", "--images-root", MISSING, "--scans-root", MISSING, *extra]


@pytest.mark.parametrize("argv, message", [
    (["synth", "--subject", "S01", "--images-root", MISSING, "--scans-root", MISSING, "--ground-truth-root", MISSING,
      "--raw-root", MISSING, "--contact-sheet", "x.png", "--settings", '{"image_size": 0}'],
     "--settings: image_size must be >= 1"),
    (["template", *expression("--targets", "t.npz", "--output-dir", MISSING,
                              "--settings", '{"lambdas": [1], "iterations": [1], "color_pool": [2]}')],
     r"--settings: unknown key(s) color_pool"),
    (["register", *expression("--targets", "t.npz", "--template-dir", MISSING, "--output", "x.obj",
                              "--settings", '{"lambdas": [1, 2], "iterations": [1]}')],
     "--settings: lambdas (2) and iterations (1) need one entry per level"),
    (["register", *expression("--targets", "t.npz", "--template-dir", MISSING, "--output", "x.obj",
                              "--settings", "[1, 2]")],
     "--settings: expected a JSON object"),
    (["metrics", *expression("--method", "gpja", "--mesh", "m.obj", "--template-dir", MISSING, "--output", "m.json",
                             "--output-dir", MISSING, "--settings", '{"samples": "many"}')],
     "--settings: samples: expected an integer"),
])
def test_bad_settings_are_refused_before_any_file_is_read(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"error: {message}" in err, err
