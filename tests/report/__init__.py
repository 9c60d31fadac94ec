"""Tests of gpja.report, a writer of tiny fake runs (metrics JSONs, registration logs, benchmark TSVs) and
readers of the tables' CSV and Markdown."""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from gpja.results import Layout

#: The two expressions of the fake runs.
E1, E2 = "1_neutral", "2_smile"


def write_metrics(results: Path, subject: str, method: str, expression: str, *, cd: float, nc: float = 0.95,
                  f05: float = 0.9, f1: float = 0.95, p2m: float | None = None, photo: tuple | None = (25.0, 0.8, 0.1),
                  corr: tuple | None = None) -> Path:
    """A metrics JSON as `gpja metrics` writes it; ``photo``: (PSNR, SSIM, LPIPS), ``corr``: (mean, median, p95)."""
    path = Layout(results).metrics(subject, method, expression)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "subject": subject, "expression": expression, "method": method, "mesh": f"{expression}.obj",
        "geometry": {"chamfer_l1_mm": cd, "mesh_to_scan_mm": cd, "scan_to_mesh_mm": cd if p2m is None else p2m,
                     "normal_consistency": nc, "fscore": {"0.5": f05, "1": f1}},
        "photometric": None if photo is None else {"psnr": photo[0], "ssim": photo[1], "lpips": photo[2],
                                                   "per_view": []},
        "correspondence": None if corr is None else {"mean_mm": corr[0], "median_mm": corr[1], "p95_mm": corr[2]},
        "seconds": {"geometry": 1.0},
    }
    path.write_text(json.dumps(record))
    return path


def write_log(results: Path, subject: str, method: str, expression: str, log: dict) -> Path:
    """A registration log beside the (absent) mesh."""
    path = Layout(results).registration_log(subject, method, expression)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(log))
    return path


def write_benchmark(path: Path, seconds: float, max_rss: float | str) -> Path:
    """A Snakemake benchmark TSV with one row."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
                    f"{seconds}\t0:00:01\t{max_rss}\t1\t1\t1\t0\t0\t50\t{seconds}\n")
    return path


def read_csv_rows(text: str) -> list[dict]:
    return list(csv.DictReader(io.StringIO(text)))


def md_row(markdown: str, label: str, occurrence: int = 0) -> list[str]:
    """The cells after the label of the ``occurrence``-th Markdown table row whose first cell is ``label``."""
    found = []
    for line in markdown.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[0] == label:
            found.append(cells[1:])
    assert len(found) > occurrence, f"no row {label!r} (#{occurrence}) in\n{markdown}"
    return found[occurrence]
