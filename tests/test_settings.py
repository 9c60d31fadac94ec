"""Settings that read themselves (gpja.settings): config sections -> dataclasses, schema agreement, load-time checks."""
from __future__ import annotations

import copy
import dataclasses
import shutil
import subprocess
import sys
import typing
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

from gpja.errors import InputError
from gpja.settings import (CONFIG_KEY, DERIVED_KEYS, HIDDEN, SECTIONS, WORKFLOW_KEYS, check_config, coerce,
                           config_key, from_section, is_settings, section_keys, settings_class, settings_section)
from tests.configs import CONFIGS, load_config

ROOT = Path(__file__).resolve().parents[1]

#: Per section, a valid value differing from the dataclass default for every key the section offers.
NON_DEFAULT = {
    "synthetic": {"seed": 7, "image_size": 64, "n_views": 3, "camera_distance_mm": 500.0, "scan_voxel_mm": 1.5,
                  "scan_noise_mm": 0.1, "distortion": False, "supersample": 1, "raw_variant": False,
                  "expressions": ["1_neutral"], "render_voxel_mm": 1.2},
    "registration.template": {"bust_edge_mm": 7.0, "lambdas": [30, 20, 10], "iterations": [4, 5, 6],
                              "refine_factor": 2.0, "lr_fraction": 0.5, "lr_decay": 0.5, "texture_size": 64,
                              "texture_iterations": 9, "texture_lr": 0.2, "faces": 900, "texture_method": "optimise",
                              "texture_size_from_images": False, "fusion_min_cos": 0.2, "fusion_feather_px": 5.0,
                              "fusion_occlusion_mm": 2.0, "fusion_robust_iterations": 0, "fusion_robust_scale": 0.1,
                              "fusion_off_scan_weight": 0.5, "fusion_scan_normals": False, "fusion_normal_blur_px": 2.0,
                              "fusion_scan_distance_mm": 7.5,
                              "texture_refine_iterations": 10,
                              "texture_refine_smoothness": 2.0, "mouth_mask": "interior", "mouth_mask_dark": 0.3},
    "registration.gpja": {"lambdas": [40, 30, 20, 10], "iterations": [1, 2, 3, 4], "refine_factor": 3.0,
                          "lr_fraction": 0.7, "lr_decay": 0.2, "color_pool": [4, 2, 1, 1], "warmup_iterations": 5,
                          "warmup_geometry": True, "optimizer_state": "per_constraint",
                          "hold_tangential": 0.05, "hold_moved_mm": [0.5, 3.0], "hold_gap_mm": [0.3, 1.5], "hold_mouth_mm": [8.0, 20.0], "hold_mouth_at_flow_mm": [6.0, 18.0], "hold_moved_at_flow": True, "mouth_stiffness": [3.0, 5.0, 15.0], "jaw_search_deg": [-20.0, 5.0], "jaw_lips_mm": [-4.0, 3.0], "jaw_shift_mm": [-3.0, 12.0], "jaw_window_mm": 25.0, "jaw_reach_mm": [35.0, 65.0], "lid_search_deg": 75.0, "lip_seal": 0.6, "color_scan_px": 5, "mask_where_open": True, "lip_spread": True, "spring_rate": 0.2, "flow_rounds": 3,
                          "flow_levels": 2, "flow_final_rounds": 1, "flow_smoothness": 12.0, "color_gradient": "tangential",
                          "flow_still_mm": 0.7, "flow_socket_margin_px": 6.0, "flow_chroma": 0.5, "flow_finest_scale": 0, "flow_scan_shading_px": 2.0, "flow_cholesky": "supernodal", "average_iterations": 6, "views_per_iteration": [3, 2, 0, 5],
                          "image_factor": [4, 2, 1, 1], "seed": 7, "face_order": "spatial", "untangle_iterations": 9, "untangle_rings": 2,
                          "untangle_turned": True, "snap_mm": 0.7, "snap_smoothness": 3.0, "color_gain": True},
    "registration.paper": {"lambdas": [40, 30], "iterations": [1, 2], "refine_factor": 3.0,
                           "lr_fraction": 0.7, "lr_decay": 0.2, "color_pool": [4, 1], "warmup_iterations": 5,
                           "warmup_geometry": True, "optimizer_state": "per_constraint",
                           "hold_tangential": 0.05, "hold_moved_mm": [0.5, 3.0], "hold_gap_mm": [0.3, 1.5], "hold_mouth_mm": [8.0, 20.0], "hold_mouth_at_flow_mm": [4.0, 9.0], "hold_moved_at_flow": True, "mouth_stiffness": [3.0, 5.0, 15.0], "jaw_search_deg": [-25.0, 0.0], "jaw_lips_mm": [-2.0, 0.0], "jaw_shift_mm": [0.0, 8.0], "jaw_window_mm": 40.0, "jaw_reach_mm": [20.0, 50.0], "lid_search_deg": 60.0, "lip_seal": 0.4, "color_scan_px": 2, "mask_where_open": True, "lip_spread": True, "spring_rate": 0.2, "flow_rounds": 1,
                           "flow_levels": 2, "flow_final_rounds": 2, "flow_smoothness": 50.0, "color_gradient": "tangential",
                           "flow_still_mm": 0.4, "flow_socket_margin_px": 4.0, "flow_chroma": 2.0, "flow_finest_scale": 2, "flow_scan_shading_px": 3.0, "flow_cholesky": "supernodal", "average_iterations": 3, "views_per_iteration": [2, 0],
                           "image_factor": [2, 1], "seed": 3, "face_order": "spatial", "untangle_iterations": 4, "untangle_rings": 0,
                           "untangle_turned": True, "snap_mm": 0.4, "snap_smoothness": 2.0, "color_gain": True},
    "baselines.nicp.settings": {"steps": [[0.5, 0.25, 3]], "gamma": 2.0, "max_distance_mm": 4.0,
                                "max_normal_angle_deg": 45.0, "reject_boundary": False, "convergence_mm": 0.5,
                                "rigid_iterations": 3, "rigid_keep": 0.5, "similarity": True,
                                "cholesky": "supernodal"},
    "metrics": {"samples": 1234, "seed": 9, "thresholds_mm": [0.25], "coverage": "distance", "max_distance_mm": 3.0,
                "correspondence_max_distance_mm": 1.5, "photometric": False},
    "figures": {"view": "3", "heatmap_max_mm": 2.0, "render_size": 128},
    "applications.remesh": {"initial_vertices": 5000, "tolerance_mm": 0.1, "tangential_tolerance_mm": None,
                            "max_vertices": 60000, "max_rounds": 3, "face_samples": 4},
    "applications.animation": {"sequence": ["1_neutral", "2_smile"], "frames_per_transition": 5, "fps": 12,
                               "size": 64, "yaw_deg": [10.0], "strip_frames": 3},
    "applications.export": {"base": "2_smile"},
    "applications.reparam": {"artist_mesh": "artists/{subject}.obj", "standin_faces": 500, "texture_size": 64,
                             "untangle_iterations": 7, "untangle_rings": 2},
}


def load(name: str) -> dict:
    return load_config(name)


def schema_node(key: str) -> dict:
    schema = yaml.safe_load((ROOT / "workflow/schemas/config.schema.yaml").read_text())
    node = schema
    for part in key.split("."):
        node = node["properties"][part]
    if "$ref" in node:  # "#/$defs/<name>": a definition shared by sections (the schedules)
        node = schema["$defs"][node["$ref"].rsplit("/", 1)[1]]
    return node


def read_back(obj, key: str):
    """The value of config key ``key`` in settings object ``obj`` (through flattened nested settings)."""
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        if is_settings(hints[f.name]):
            if key in section_keys(hints[f.name]) and key not in f.metadata.get(HIDDEN, ()):
                return read_back(getattr(obj, f.name), key)
        elif config_key(f) == key:
            return getattr(obj, f.name)
    raise KeyError(key)


def as_config_value(value):
    """A settings value as it reads back: tuples for lists, dataclass items as their field tuples."""
    if isinstance(value, (list, tuple)):
        return tuple(as_config_value(v) for v in value)
    if dataclasses.is_dataclass(value):
        return tuple(dataclasses.astuple(value))
    return value


# ---------------------------------------------------------------------------- from_section on toy classes

@dataclass(frozen=True)
class Inner:
    a: float = 1.0
    b: tuple[int, ...] = (1, 2)
    c: int | None = None

    def __post_init__(self):
        if len(self.b) < 1:
            raise ValueError("b needs an entry")


@dataclass(frozen=True)
class Item:
    x: float
    n: int


@dataclass(frozen=True)
class Outer:
    name: str = "x"
    inner: Inner = field(default_factory=lambda: Inner(a=5.0), metadata={HIDDEN: ("c",)})
    count: int = field(default=3, metadata={CONFIG_KEY: "n_things"})
    flag: bool = True
    items: tuple[Item, ...] = ()

    from_config = classmethod(from_section)


def test_defaults_come_from_the_dataclass():
    assert Outer.from_config(None) == Outer() == Outer.from_config({})
    assert section_keys(Outer) == ("name", "a", "b", "n_things", "flag", "items")


def test_lists_become_tuples_and_numbers_take_the_field_type():
    s = Outer.from_config({"b": [3, 4.0], "a": 2, "n_things": 7.0, "items": [[1, 2], {"x": 3, "n": 4}]})
    assert s.inner == Inner(a=2.0, b=(3, 4)) and type(s.inner.a) is float and type(s.inner.b[1]) is int
    assert s.count == 7 and type(s.count) is int
    assert s.items == (Item(1.0, 2), Item(3.0, 4)) and type(s.items[0].x) is float


def test_nested_settings_keep_the_field_default_for_absent_keys():
    assert Outer.from_config({"b": [9]}).inner == Inner(a=5.0, b=(9,))  # a from Outer's default Inner, not Inner()


@pytest.mark.parametrize("section, match", [
    ({"nme": "y"}, r"src: unknown key\(s\) nme; known: name, a, b, n_things, flag, items"),
    ({"c": 1}, r"unknown key\(s\) c"),  # hidden nested key
    ({"count": 1}, r"unknown key\(s\) count"),  # the field name when its config key differs
    ({"a": "big"}, "a: expected a number"),
    ({"a": True}, "a: expected a number"),
    ({"n_things": 2.5}, "n_things: expected an integer"),
    ({"flag": 1}, "flag: expected true or false"),
    ({"name": 3}, "name: expected a string"),
    ({"b": 3}, "b: expected a list"),
    ({"b": [1, "x"]}, r"b\[1\]: expected an integer"),
    ({"b": []}, "b needs an entry"),  # __post_init__ of the nested settings
    ({"items": [[1]]}, r"items\[0\]: expected \[x, n\]"),
    ({"items": [{"x": 1, "m": 2}]}, r"items\[0\]: unknown key\(s\) m"),
])
def test_bad_sections_name_the_source_and_the_key(section, match):
    with pytest.raises(InputError, match=match) as err:
        Outer.from_config(section, "src")
    assert str(err.value).startswith("src: ")


def test_a_section_must_be_a_mapping():
    with pytest.raises(InputError, match="src: expected a mapping"):
        Outer.from_config([1, 2], "src")


def test_coerce_optional_and_fixed_tuples():
    assert coerce(None, int | None, "k") is None and coerce(2.0, int | None, "k") == 2
    assert coerce([1, 2], tuple[float, int], "k") == (1.0, 2)
    with pytest.raises(ValueError, match="k: expected 2 entries"):
        coerce([1], tuple[float, int], "k")


# ---------------------------------------------------------------------------- the project's settings classes

@pytest.mark.parametrize("key", SECTIONS)
def test_every_settings_class_reads_its_defaults(key):
    cls = settings_class(key)
    assert cls.from_config({}) == cls()


@pytest.mark.parametrize("key", SECTIONS)
def test_schema_and_dataclass_agree(key):
    """Every key of a settings class is a property of its schema section, and vice versa (minus the workflow's own)."""
    cls = settings_class(key)
    fields = set(section_keys(cls)) - set(DERIVED_KEYS.get(key, ()))
    node = schema_node(key)
    assert node.get("additionalProperties") is False, f"{key}: the schema must refuse unknown keys"
    properties = set(node["properties"]) - set(WORKFLOW_KEYS.get(key, ()))
    assert fields - properties == set(), f"{key}: settings fields missing from the schema"
    assert properties - fields == set(), f"{key}: schema properties that are no settings field"


@pytest.mark.parametrize("key", SECTIONS)
def test_every_field_is_settable_from_config(key):
    cls = settings_class(key)
    values = NON_DEFAULT[key]
    assert set(values) == set(section_keys(cls)), f"{key}: NON_DEFAULT must cover every key"
    built = cls.from_config(values, key)
    default = cls()
    for k, v in values.items():
        got = as_config_value(read_back(built, k))
        assert got == as_config_value(v), (k, got, v)
        assert got != as_config_value(read_back(default, k)), f"{key}.{k}: pick a non-default value"
    for k, v in values.items():  # one at a time, too: no key depends on another being set
        if k not in ("lambdas", "iterations", "color_pool", "views_per_iteration", "image_factor"):  # one entry per level
            assert as_config_value(read_back(cls.from_config({k: v}, key), k)) == as_config_value(v)


def test_template_schedule_reads_the_flat_section_as_the_cli_did():
    """The CI config's template section builds the same settings as the CLI's hand-written reader did."""
    from gpja.register.multiscale import Schedule
    from gpja.register.template import TemplateSettings

    cfg = load("ci.yaml")["registration"]
    t = TemplateSettings.from_config(cfg["template"])
    assert t == TemplateSettings(bust_edge_mm=8.0, texture_size=256, texture_iterations=100, texture_lr=0.05,
                                 template_faces=8000,
                                 schedule=Schedule(lambdas=(200.0, 120.0), iterations=(90, 90), refine_factor=2.5,
                                                   lr_fraction=1.0, lr_decay=0.3))
    assert Schedule.from_config(cfg["gpja"]) == Schedule(lambdas=(100.0, 50.0), iterations=(120, 120),
                                                         lr_fraction=1.0, lr_decay=0.3, warmup_iterations=0,
                                                         optimizer_state="per_constraint")


def test_the_template_section_offers_no_colour_keys():
    from gpja.register.template import TemplateSettings

    with pytest.raises(InputError, match=r"unknown key\(s\) color_pool"):
        TemplateSettings.from_config({"lambdas": [1], "iterations": [1], "color_pool": [2]}, "registration.template")


# ---------------------------------------------------------------------------- check_config: load-time cross-field rules

@pytest.mark.parametrize("name", CONFIGS)
def test_shipped_configs_pass(name):
    built = check_config(load(name))
    assert {"registration.template", "registration.gpja", "metrics"} <= set(built)


def broken(change) -> dict:
    cfg = copy.deepcopy(load("ci.yaml"))
    change(cfg)
    return cfg


@pytest.mark.parametrize("change, match", [
    (lambda c: c["registration"]["gpja"].update(lambdas=[100, 50, 25]),
     r"^registration\.gpja: lambdas \(3\) and iterations \(2\) need one entry per level"),
    (lambda c: c["registration"]["template"].update(iterations=[90]),
     r"^registration\.template: lambdas \(2\) and iterations \(1\)"),
    (lambda c: c["registration"]["gpja"].update(color_pool=[2, 2, 1]),
     r"^registration\.gpja: color_pool needs one entry >= 1 per level \(2\)"),
    (lambda c: c["baselines"]["nicp"]["settings"].update(steps=[[0.1, 1, 0]]),
     r"^baselines\.nicp\.settings: steps\[0\]: stiffness must be > 0"),
    (lambda c: c["synthetic"].update(image_size=0), r"^synthetic: image_size must be >= 1"),
    (lambda c: c.update(expressions=["1_neutral", "99_unknown"]), r"^synthetic: unknown synthetic expressions"),
])
def test_cross_field_errors_name_the_config_key(change, match):
    with pytest.raises(InputError, match=match) as err:
        check_config(broken(change))
    assert "\n" not in str(err.value)


def test_unused_sections_are_not_checked():
    cfg = broken(lambda c: (c["synthetic"].update(enabled=False), c.update(expressions=["1_neutral", "99_unknown"]),
                            c["baselines"]["nicp"].update(enabled=False, settings={"steps": []}),
                            c["applications"].update(enabled=False, animation={"size": -1})))
    assert set(check_config(cfg)) == {"registration.template", "registration.gpja", "registration.paper", "metrics"}


def test_the_synthetic_section_gets_the_runs_expressions():
    cfg = load("ci.yaml")
    section = settings_section(cfg, "synthetic")
    assert "enabled" not in section and "raw_root" not in section
    assert section["expressions"] == ["1_neutral", "3_mouth_stretch", "12_lip_puckerer", "13_lip_funneler"]


def test_dry_run_stops_on_a_cross_field_error(tmp_path):
    """``snakemake -n`` refuses a config whose gpja lambdas and iterations differ in length, naming the key."""
    for item in ("Snakefile", "workflow", "config"):
        src = ROOT / item
        (shutil.copytree if src.is_dir() else shutil.copy)(src, tmp_path / item)
    cfg = broken(lambda c: c["registration"]["gpja"].update(lambdas=[100, 50, 25]))
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(cfg))
    out = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "1", "--configfile", "bad.yaml"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode != 0
    assert "registration.gpja: lambdas (3) and iterations (2) need one entry per level" in out.stdout + out.stderr


def test_applications_expressions_must_be_in_the_run():
    config = load("config.yaml")
    config["applications"]["animation"]["sequence"] = ["1_neutral", "20_brow_lower"]
    with pytest.raises(InputError, match="applications.animation.*20_brow_lower"):
        check_config(config)
    config = load("config.yaml")
    config["applications"]["export"]["base"] = "5_jaw_left"
    with pytest.raises(InputError, match="applications.export.*5_jaw_left"):
        check_config(config)
    config["applications"]["enabled"] = False  # not run: not checked
    check_config(config)
    config = load("config.yaml")
    del config["applications"]["animation"]  # the defaults are checked too
    config["expressions"] = ["1_neutral", "13_lip_funneler"]
    with pytest.raises(InputError, match="2_smile"):
        check_config(config)
