"""The fake run most report tests read (tests/report/__init__.py writes its files)."""
from __future__ import annotations

import pytest

from tests.report import E1, E2, write_metrics


@pytest.fixture
def run_dir(tmp_path):
    """S01, S02 x 1_neutral, 2_smile x gpja (textured), nicp (better N.C. on S02), nphm (imported, no UVs)."""
    res = tmp_path / "results"
    gpja_cd = {("S01", E1): 0.1, ("S01", E2): 0.3, ("S02", E1): 0.2, ("S02", E2): 0.4}
    nicp_cd = {("S01", E1): 0.5, ("S01", E2): 0.7, ("S02", E1): 0.4, ("S02", E2): 0.6}
    photo = {E1: (24.0, 0.75, 0.08), E2: (26.0, 0.77, 0.10)}
    for (s, e), cd in gpja_cd.items():
        write_metrics(res, s, "gpja", e, cd=cd, nc=0.98, f05=0.9, f1=0.96, photo=photo[e], corr=(1.0, 0.5, 3.0))
    for (s, e), cd in nicp_cd.items():
        write_metrics(res, s, "nicp", e, cd=cd, nc=0.92 if s == "S01" else 0.99, f05=0.7, f1=0.85,
                      photo=(20.0, 0.6, 0.2), corr=(2.0, 1.0, 5.0))
        write_metrics(res, s, "nphm", e, cd=0.2 if s == "S01" else 0.8, nc=0.9, f05=0.8, f1=0.9, photo=None)
    return res
