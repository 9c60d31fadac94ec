"""The paper's applications ("Applications" in the paper): what a subject's registered meshes are for.

- ``remesh``: every expression on one triangulation defined in the template's texture space.
- ``animate``: linear interpolation between remeshed expressions, rendered frames, video.
- ``reparam``: an artist's UV-unwrapped mesh carried onto every expression (the paper's map phi_b phi_a^-1).
- ``export``: the remeshed expressions as one glTF 2.0 binary with morph targets (blendshapes).

Layering (DESIGN.md): ``apply`` reads what ``register`` wrote and may use ``render`` and ``metrics``; it never
reads the synthetic ground truth.
"""
