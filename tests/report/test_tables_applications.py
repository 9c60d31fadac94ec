"""gpja.report.tables_applications: the artist mesh's turned faces per hop, from each subject's turns.json."""
from __future__ import annotations

import pytest

from gpja.errors import InputError
from gpja.io import write_json
from gpja.report import tables as T
from gpja.report.formats import to_csv, to_markdown
from gpja.report.tables_applications import turns_table
from gpja.results import Layout
from tests.report import read_csv_rows


def write_turns(results, subject, hops, truth=True):
    rows = []
    for k, (parent, expression) in enumerate(hops):
        row = {"parent": parent, "expression": expression, "turned": 10 + k, "turned_observed": 5 + k}
        if truth:
            row.update(truth_turned=k, truth_turned_observed=k, both=min(k, 1), near_truth=2 * k, faces_compared=300)
        rows.append(row)
    write_json(Layout(results).reparam_turns(subject), {"subject": subject, "faces": 300, "observed_faces": 200,
                                                        "hops": rows, "truth": {} if truth else None})


def test_turns_table_has_a_row_per_hop_and_dashes_without_truth(tmp_path):
    write_turns(tmp_path, "S01", [("3_mouth_stretch", "1_neutral"), ("1_neutral", "18_eye_closed")])
    write_turns(tmp_path, "S02", [("3_mouth_stretch", "1_neutral")], truth=False)
    table = turns_table(tmp_path, ["S01", "S02"])
    md = to_markdown(table)
    assert "| Subject S01 | 1_neutral → 18_eye_closed | 11 | 6 | 1 | 1 | 1 | 2 |" in md
    assert "| Subject S02 | 3_mouth_stretch → 1_neutral | 10 | 5 | – | – | – | – |" in md
    rows = read_csv_rows(to_csv(table))
    assert [r["expression"] for r in rows] == ["1_neutral", "18_eye_closed", "1_neutral"]
    assert rows[1]["truth_turned"] == "1" and rows[2]["truth_turned"] == "" and rows[0]["faces"] == "300"


def test_turns_table_is_a_default_table_only_when_every_subject_has_its_counts(tmp_path):
    from tests.report import E1, write_metrics

    for s in ("S01", "S02"):
        write_metrics(tmp_path, s, "gpja", E1, cd=0.1)
    write_turns(tmp_path, "S01", [("a", "b")])
    run = T.load_run(tmp_path, ["S01", "S02"], ["gpja"], [E1])
    assert "turns" not in T.default_tables(run, results=tmp_path)
    write_turns(tmp_path, "S02", [("a", "b")])
    assert "turns" in T.default_tables(run, results=tmp_path)


def test_turns_table_names_a_missing_or_corrupt_file(tmp_path):
    with pytest.raises(InputError, match="turns.json: file not found|turns.json"):
        turns_table(tmp_path, ["S01"])
    write_json(Layout(tmp_path).reparam_turns("S01"), {"subject": "S01"})
    with pytest.raises(InputError, match="no 'hops' list"):
        turns_table(tmp_path, ["S01"])
