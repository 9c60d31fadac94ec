"""gpja.report.published: the transcribed paper tables agree with themselves."""
from __future__ import annotations

import statistics

import pytest

from gpja.report import published as P


def test_transcribed_paper_tables_agree_with_the_paper_average_row():
    for label, average in P.PUBLISHED_PHOTOMETRIC_AVERAGE.items():
        rows = P.PUBLISHED_PHOTOMETRIC[label].values()
        for i, digits in enumerate((2, 4, 5)):
            assert round(statistics.fmean(r[i] for r in rows), digits) == pytest.approx(average[i])
    assert all(len(per) == 7 for per in P.PUBLISHED_GEOMETRY.values())
    assert P.paper_subject("007") == "7" and P.paper_subject("S01") == "S01"
