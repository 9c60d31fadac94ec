"""The applications' table: faces the re-parametrised artist mesh turns over along the registration tree's hops
(``reparam/turns.json``, ``gpja.metrics.turns``), beside the true motion's count on synthetic data."""
from __future__ import annotations

from pathlib import Path

from gpja.errors import InputError
from gpja.metrics.turns import NEAR_TRUTH_MM
from gpja.report.table_model import Block, Cell, Table, subject_label
from gpja.results import Layout

#: The counts of one hop, in column order (``gpja.metrics.turns.hop_turns``); the last four need ground truth.
TURN_COUNTS = ("turned", "turned_observed", "truth_turned", "truth_turned_observed", "both", "near_truth")


def read_turns(results: str | Path, subject: str) -> dict:
    """A subject's ``reparam/turns.json``. Raises InputError when it is missing, corrupt or has no hops."""
    from gpja.io import read_json

    path = Layout(results).reparam_turns(subject)
    record = read_json(path)
    if not isinstance(record, dict) or not isinstance(record.get("hops"), list):
        raise InputError(path, "no 'hops' list (not written by gpja turns?)")
    return record


def turns_table(results: str | Path, subjects) -> Table:
    """Per subject and hop of its registration tree: the artist mesh's faces turned over (all, on observed
    material), and with ground truth the true motion's (all, observed) and how many both turn."""
    records = {s: read_turns(results, s) for s in subjects}
    rows, csv_rows, rules = [], [], set()
    for s in subjects:
        if rows:
            rules.add(len(rows))
        for hop in records[s]["hops"]:
            rows.append([subject_label(s), f"{hop['parent']} → {hop['expression']}"]
                        + [Cell(hop.get(k), 0) for k in TURN_COUNTS])
            csv_rows.append([s, hop["parent"], hop["expression"], *[hop.get(k) for k in TURN_COUNTS],
                             records[s].get("faces"), records[s].get("observed_faces")])
    block = Block(headers=["Subject", "Hop", "turned", "observed", "turned", "observed", "turned", "near"], rows=rows,
                  label_columns=2, groups=[("GPJA", 2), ("true motion", 2), ("both", 1), ("GPJA", 1)], rules=rules)
    faces = sorted({r.get("faces") for r in records.values()})
    notes = [(f"Faces of the artist mesh ({', '.join(str(f) for f in faces)}) whose normal turns by more than 90 "
              "degrees from the parent expression (the one its registration started from) to the expression. "
              "Observed: on material a camera saw in the template expression (template/texture_observed.png). "
              "True motion: the artist mesh carried by the synthetic generator's own maps of space instead "
              "(gpja/metrics/turns.py); both: turned by GPJA and by the true motion; GPJA near: GPJA's turned "
              f"faces within {NEAR_TRUTH_MM:g} mm of one the true motion turns. A closing eye turns faces over in "
              "truth: the template's one skin over lid and eyeball folds under the closing lid.")]
    caption = "The artist mesh's faces turned over between adjacent expressions (issue 16's bar: none)."
    return Table("turns", caption, [block],
                 ["subject", "parent", "expression", *TURN_COUNTS, "faces", "observed_faces"], csv_rows, notes)
