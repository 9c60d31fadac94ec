"""gpja.report.table_model: bolding the best printed value, labels and headers."""
from __future__ import annotations

from gpja.report.table_model import Block, Cell, header, mark_best, paper_label, subject_label


def test_bold_ties_at_printed_precision_and_never_reference_rows():
    block = Block(["M", "x"], [["a", Cell(0.1004, 3)], ["b", Cell(0.0996, 3)], ["c", Cell(0.2, 3)]],
                  better=[None, "min"])
    mark_best(block)
    assert [r[1].bold for r in block.rows] == [True, True, False]
    block = Block(["M", "x"], [["a", Cell(0.3, 3)], ["b", Cell(0.2, 3)], ["paper", Cell(0.1, 3)]],
                  reference_rows={2}, better=[None, "min"])
    mark_best(block)
    assert [r[1].bold for r in block.rows] == [False, True, False]


def test_cells_headers_and_labels():
    assert Cell(None, 3).text() == "–" and Cell(0.12345, 2).text() == "0.12"
    assert header("fscore@1") == "F@1.0 ↑" and header("fscore@0.5") == "F@0.5 ↑"
    assert header("chamfer_l1_mm") == "C.D. (mm) ↓"
    assert paper_label("GPJA") == "GPJA (paper)" and paper_label(("a", "b")) == ("a (paper)", "b (paper)")
    assert subject_label("7") == "Subject 7" and subject_label("Average") == "Average"
