"""Procedural synthetic benchmark in FaceScape's layout, with exact ground truth.

Modules: :mod:`head` (identity + rest SDF), :mod:`expressions` (action units,
phi_e), :mod:`albedo` (procedural rest-space texture), :mod:`landmarks`
(iBUG-68), :mod:`scan` (independent, partial scan triangulation),
:mod:`capture` (rig, SH lighting, ray-cast rendering), :mod:`writer`
(layout, raw variant, contact sheet).
"""
from gpja.data.synthetic.expressions import DEFAULT_EXPRESSIONS, EXPRESSIONS, map_to_expression
from gpja.data.synthetic.writer import GENERATOR_VERSION, SynthConfig, subject_seed_index, synthesize_subject

__all__ = ["EXPRESSIONS", "DEFAULT_EXPRESSIONS", "SynthConfig", "synthesize_subject", "map_to_expression",
           "GENERATOR_VERSION", "subject_seed_index"]
