"""The render backend reaches every render of template creation and registration.

A spy wrapping the CPU renderer stands in for another backend: it must be called for every render,
and the result must be bit for bit the default's (None = the CPU renderer).
"""
from __future__ import annotations

import numpy as np
import torch

from gpja.lighting import uniform_sh
from gpja.mesh import TexturedMesh
from gpja.register import pipeline, template
from gpja.register.hra import ExpressionTargets, Switches
from gpja.register.multiscale import Schedule, optimise
from gpja.register.texture_fusion import FusionSettings
from gpja.render import render_views
from tests.register.test_multiscale import ellipsoid_targets, start_mesh
from tests.render.scenes import ring_cameras, sphere, spherical_uv


class Spy:
    """A render function that records each call's passes and renders with the CPU renderer."""

    def __init__(self):
        self.passes = []

    def __call__(self, V, topology, cameras, passes, **kwargs):
        self.passes.append(tuple(passes))
        return render_views(V, topology, cameras, passes, **kwargs)


def test_optimise_renders_every_iteration_with_the_given_function():
    _, _, targets = ellipsoid_targets(size=32)
    schedule = Schedule(lambdas=(20.0, 10.0), iterations=(4, 3))
    kwargs = dict(texture=torch.ones(4, 4, 3), mask_texture=torch.ones(4, 4, 1), progress_every=0)
    spy = Spy()
    default, _ = optimise(start_mesh(), targets, Switches(color=False), schedule, **kwargs)
    spied, _ = optimise(start_mesh(), targets, Switches(color=False), schedule, render=spy, **kwargs)
    assert spy.passes == [("depth",), ("normal",)] * 2 + [("depth",), ("normal",), ("depth",)]
    np.testing.assert_array_equal(spied.V, default.V)
    np.testing.assert_array_equal(spied.F, default.F)


def textured_scene(size=32):
    V, F = sphere(subdivisions=3, radius=60.0)
    mesh = TexturedMesh(V, F, spherical_uv(V), F, np.full((16, 16, 3), 0.5, np.float32))
    cams = ring_cameras(2, size)
    images = torch.rand(2, size, size, 3, generator=torch.Generator().manual_seed(0))
    zeros = torch.zeros(2, size, size, 1)
    targets = ExpressionTargets(cams, images, zeros, torch.zeros(2, size, size, 3), zeros,
                                torch.tensor(uniform_sh(), dtype=torch.float32))
    return mesh, targets


def test_registration_renders_with_the_given_function():
    mesh, targets = textured_scene()
    mask = np.ones((8, 8), np.float32)
    schedule = Schedule(lambdas=(10.0,), iterations=(3,))
    spy = Spy()
    default, _ = pipeline.register(mesh, mask, targets, schedule, Switches(), progress=lambda m: None)
    spied, _ = pipeline.register(mesh, mask, targets, schedule, Switches(), progress=lambda m: None, render=spy)
    # the uncovered-views check, then one constraint per iteration
    assert spy.passes == [(), ("color", "mask"), ("depth",), ("normal",)]
    np.testing.assert_array_equal(spied.V, default.V)


def test_texture_reconstruction_renders_with_the_given_function():
    mesh, targets = textured_scene()
    spy = Spy()
    default = template.reconstruct_texture(mesh, targets, 32, 5, 0.05, progress=lambda m: None)
    spied = template.reconstruct_texture(mesh, targets, 32, 5, 0.05, progress=lambda m: None, render=spy)
    assert spy.passes == [("normal", "uv")]
    np.testing.assert_array_equal(spied, default)


def test_create_template_passes_the_function_to_the_fit_and_the_texture(monkeypatch):
    mesh, targets = textured_scene()
    seen = {}

    def fake_optimise(start, targets, switches, schedule, *, render=None, **kwargs):
        seen["fit"] = render
        return start, type("Log", (), {"to_json": lambda self: {}})()

    def fake_texture(fitted, targets, size, iterations, lr, progress, render=None, **kwargs):
        seen["texture"] = render
        return np.full((size, size, 3), 0.5, np.float32)

    monkeypatch.setattr(template, "optimise", fake_optimise)
    monkeypatch.setattr(template, "reconstruct_texture", fake_texture)
    monkeypatch.setattr(template, "place_bust", lambda bust, scan_V: bust)
    monkeypatch.setattr(template, "decimate_with_texture", lambda dense, faces: dense)
    quiet = dict(progress=lambda m: None, lighting="uniform")
    # the bust is not placed on the scene here, so no texel is near the "scan": the off-scan test is off
    off_scan_test_off = FusionSettings(fusion_scan_distance_mm=0.0)
    # the paper's texture optimisation gets the function
    spy = Spy()
    settings = template.TemplateSettings(bust_edge_mm=12.0, texture_size=16, texture_method="optimise",
                                         fusion=off_scan_test_off)
    template.create_template(mesh.V, targets, settings, render=spy, **quiet)
    assert seen == {"fit": spy, "texture": spy} and spy.passes == [("depth",)]  # + the fusion's depth buffer
    # the fusion renders its depth buffers with it, bit for bit as the default renderer
    spy = Spy()
    settings = template.TemplateSettings(bust_edge_mm=12.0, texture_size=16, fusion=off_scan_test_off)
    fused = template.create_template(mesh.V, targets, settings, render=spy, **quiet)
    default = template.create_template(mesh.V, targets, settings, **quiet)
    assert spy.passes == [("depth",)]
    np.testing.assert_array_equal(fused.mesh.texture, default.mesh.texture)
