"""The paper's published numbers (FaceScape subjects), transcribed from paper/gpja.tex, for ``--published facescape``.

Each table maps a row label to its values per FaceScape subject (as the paper writes the id: ``7``, not
``007``), in the order of its ``PAPER_*_KEYS``. :func:`published_stats` picks the run's subjects.
"""
from __future__ import annotations

from gpja.report.runs import AVERAGE, means

#: The values ``--published`` accepts.
PUBLISHED_CHOICES = ("facescape",)

PAPER_GEOMETRY_KEYS = ("chamfer_l1_mm", "normal_consistency", "fscore@0.5", "fscore@1")
# Table 1 (\label{tab:geoMetric}), "Geometric evaluations on 10 expressions per subject in millimeter":
# C.D. (mm), N.C., F@0.5, F@1.0 per FaceScape subject. The paper's "NICP" row is FaceScape's own
# topologically uniform (TU) meshes, obtained by NICP; "NPHM" is the NPHM model's output.
PUBLISHED_GEOMETRY = {
    "NICP": {"7": (0.477, 0.910, 0.708, 0.852), "32": (0.355, 0.942, 0.800, 0.918),
             "122": (0.404, 0.943, 0.738, 0.901), "212": (0.614, 0.915, 0.549, 0.799),
             "340": (0.383, 0.944, 0.743, 0.913), "344": (0.340, 0.936, 0.792, 0.922),
             "350": (0.428, 0.912, 0.746, 0.879)},
    "NPHM": {"7": (0.347, 0.958, 0.814, 0.923), "32": (0.377, 0.970, 0.778, 0.925),
             "122": (0.325, 0.968, 0.825, 0.945), "212": (0.429, 0.949, 0.731, 0.899),
             "340": (0.285, 0.973, 0.858, 0.956), "344": (0.338, 0.957, 0.814, 0.938),
             "350": (0.489, 0.937, 0.682, 0.872)},
    "GPJA": {"7": (0.229, 0.981, 0.909, 0.960), "32": (0.147, 0.992, 0.957, 0.975),
             "122": (0.264, 0.984, 0.880, 0.959), "212": (0.180, 0.980, 0.921, 0.963),
             "340": (0.215, 0.981, 0.912, 0.961), "344": (0.224, 0.975, 0.912, 0.960),
             "350": (0.239, 0.970, 0.891, 0.957)},
}
# Table 2 (\label{tab:ImgMetric}), "Photometric evaluations on 10 expressions per subject" (GPJA only):
# PSNR (dB), SSIM, LPIPS per FaceScape subject; the paper's "Average" row (the mean of the subject rows)
# is kept for reference: the table prints the mean over the subjects of the run instead.
PUBLISHED_PHOTOMETRIC = {
    "GPJA": {"7": (24.75, 0.7810, 0.06868), "32": (20.79, 0.6621, 0.07516), "122": (23.56, 0.7443, 0.07081),
             "212": (25.51, 0.7699, 0.09368), "340": (24.10, 0.7378, 0.06802), "344": (23.08, 0.7569, 0.06791),
             "350": (25.38, 0.7320, 0.07857)},
}
PUBLISHED_PHOTOMETRIC_AVERAGE = {"GPJA": (23.88, 0.7406, 0.07469)}
PAPER_ABLATION_KEYS = ("scan_to_mesh_mm", "psnr", "ssim", "lpips")
# Table 3 (\label{tab:alba}), ablations "on four publishable subjects" (not named in the paper): geometric error
# (the point-to-mesh distance, mm), PSNR (dB), SSIM, LPIPS. The paper has no "w/o mask" row.
PUBLISHED_ABLATION = {
    "gpja": (0.167, 24.06, 0.7523, 0.07511),
    "gpja-no_normal": (0.377, 24.49, 0.7498, 0.07578),
    "gpja-no_depth": (0.455, 23.67, 0.7535, 0.07544),
    "gpja-no_color": (0.447, 22.04, 0.7364, 0.07820),
}


def paper_subject(subject: str) -> str:
    """FaceScape subject id as the paper writes it (``007`` -> ``7``)."""
    return (subject.lstrip("0") or "0") if subject.isdigit() else subject


def published_stats(table: dict, keys, subjects) -> dict[str, dict[str, dict[str, float | None]]]:
    """``{label: {subject: {metric: value}}}`` of a published table for the run's ``subjects`` (None where
    the paper has no such subject), plus ``AVERAGE``: the mean over the subjects the paper has."""
    out = {}
    for label, per_subject in table.items():
        rows = {s: dict(zip(keys, per_subject[paper_subject(s)])) for s in subjects if paper_subject(s) in per_subject}
        out[label] = {s: rows.get(s, dict.fromkeys(keys)) for s in subjects}
        out[label][AVERAGE] = means(list(rows.values()), keys)
    return out
