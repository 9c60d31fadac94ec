"""Tables against the synthetic ground truth: correspondence by region, texture quality, the oracle in Tables 1-2."""
from __future__ import annotations

import json

import pytest

from gpja.cli import main
from gpja.errors import InputError
from gpja.metrics.regions import REGIONS
from gpja.report import tables as T
from gpja.report.formats import to_csv, to_markdown
from gpja.report.regression import check_regression, write_reference
from gpja.report.runs import load_run
from gpja.report.tables_truth import correspondence_regions_table, position_regions_table, texture_table
from gpja.results import Layout
from tests.report import E1, E2, md_row, read_csv_rows, write_metrics


def add_regions(results, subject, method, expression, median: float):
    """Add per-region correspondence scores (region k: median + k, mean + k + 0.5; no brows) to a metrics JSON."""
    path = Layout(results).metrics(subject, method, expression)
    record = json.loads(path.read_text())
    record["correspondence"]["regions"] = {
        r: ({"median_mm": median + k, "mean_mm": median + k + 0.5, "p95_mm": 9.0, "count": 10} if r != "brows"
            else {"median_mm": None, "mean_mm": None, "p95_mm": None, "count": 0}) for k, r in enumerate(REGIONS)}
    path.write_text(json.dumps(record))


def add_position(results, subject, method, expression, median: float):
    """Add the position error (overall: median, median + 1, median + 5; region k: median + k) to a metrics JSON."""
    path = Layout(results).metrics(subject, method, expression)
    record = json.loads(path.read_text())
    record["correspondence"]["position"] = {
        "median_mm": median, "mean_mm": median + 1.0, "p95_mm": median + 5.0, "max_mm": 20.0, "n_used": 10,
        "fraction_used": 1.0, "present_mm": 0.5,
        "regions": {r: {"median_mm": median + k, "mean_mm": median + k, "p95_mm": 9.0, "count": 10}
                    for k, r in enumerate(REGIONS)}}
    path.write_text(json.dumps(record))


def test_position_regions_table_means_per_subject_and_method(run_dir):
    for s in ("S01", "S02"):
        for e, base in ((E1, 1.0), (E2, 3.0)):
            add_position(run_dir, s, "gpja", e, base if s == "S01" else base + 2)
            add_position(run_dir, s, "nicp", e, 0.5)
    run = load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    table = position_regions_table(run)
    rows = {(r["subject"], r["method"]): r for r in read_csv_rows(to_csv(table))}
    assert float(rows[("S01", "gpja")]["position_median_mm"]) == pytest.approx(2.0)  # (1 + 3) / 2
    assert float(rows[("S01", "gpja")]["position_p95_mm"]) == pytest.approx(7.0)
    assert float(rows[("S02", "gpja")]["position_mouth_median_mm"]) == pytest.approx(4.0)
    assert float(rows[("Average", "gpja")]["position_eyes_mean_mm"]) == pytest.approx(4.0)  # (3 + 5) / 2
    md = to_markdown(table)
    assert md_row(md, "Subject S01")[:5] == ["GPJA", "3.000", "2.000", "7.000", "2.000"]  # mean, median, p95, mouth
    assert "all P95 (mm) ↓" in md and "mouth/lips Median (mm) ↓" in md
    assert "position_regions" in T.default_tables(run)
    # metrics written before the position error: not offered, and asking for it says why
    bare = load_run(run_dir, ["S01"], ["nphm"], [E1])
    assert "position_regions" not in T.default_tables(bare)
    with pytest.raises(InputError, match="no position error"):
        position_regions_table(bare)


def add_floor(results, subject, method, expression, median: float):
    """Add the correspondence score's floor (overall: median, median + 1, median + 4; region k: median + k)."""
    path = Layout(results).metrics(subject, method, expression)
    record = json.loads(path.read_text())
    record["correspondence"]["floor"] = {
        "median_mm": median, "mean_mm": median + 1.0, "p95_mm": median + 4.0, "max_mm": 20.0, "n_used": 10,
        "fraction_used": 1.0,
        "regions": {r: {"median_mm": median + k, "mean_mm": median + k, "p95_mm": 9.0, "count": 10}
                    for k, r in enumerate(REGIONS)}}
    path.write_text(json.dumps(record))


def test_each_method_s_floor_is_a_row_under_it_in_the_correspondence_tables(run_dir):
    for s in ("S01", "S02"):
        for e in (E1, E2):
            add_regions(run_dir, s, "gpja", e, 1.0)
            add_regions(run_dir, s, "nicp", e, 0.5)
            add_floor(run_dir, s, "gpja", e, 0.2 if e == E1 else 0.6)  # nicp's records have none (older metrics)
    run = load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    regions = {(r["subject"], r["method"], r["region"]): r for r in read_csv_rows(to_csv(correspondence_regions_table(run)))}
    assert float(regions[("S01", "gpja:floor", "eyes")]["median_mm"]) == pytest.approx(0.4 + REGIONS.index("eyes"))
    assert regions[("Average", "gpja:floor", "mouth")]["expressions"] == "4"
    assert not any(m == "nicp:floor" for _, m, _ in regions)
    md = to_markdown(T.correspondence_table(run))
    labels = [line.split(" | ")[1] for line in md.splitlines() if line.startswith("| Average")]
    assert labels == ["GPJA", "GPJA floor", "NICP"]  # the floor right under its method
    assert [line for line in md.splitlines() if line.startswith("| Average | GPJA floor")] == [
        "| Average | GPJA floor | 1.400 | 0.400 | 4.400 |"]  # mean, median, p95: (E1 + E2) / 2
    assert "No vertex scores below its floor" in md
    # metrics written before the floor: no row, no note; the regression check never reads the floor
    for s in ("S01", "S02"):
        for e in (E1, E2):
            path = Layout(run_dir).metrics(s, "gpja", e)
            record = json.loads(path.read_text())
            del record["correspondence"]["floor"]
            path.write_text(json.dumps(record))
    md = to_markdown(T.correspondence_table(load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])))
    assert "floor" not in md


def write_oracle(results, subject, expression, psnr: float, cd: float | None = None, nc: float = 1.0):
    """The oracle's metrics JSON (`gpja oracle`): photometric, and with ``cd`` the true surface's geometric scores
    (without: as the oracle wrote it before it scored geometry)."""
    path = Layout(results).metrics(subject, "oracle", expression)
    path.parent.mkdir(parents=True, exist_ok=True)
    geometry = None if cd is None else {"chamfer_l1_mm": cd, "mesh_to_scan_mm": cd, "scan_to_mesh_mm": cd,
                                        "normal_consistency": nc, "fscore": {"0.5": 1.0, "1": 1.0}}
    path.write_text(json.dumps({"subject": subject, "expression": expression, "method": "oracle",
                                "geometry": geometry,
                                "photometric": {"psnr": psnr, "ssim": 0.99, "lpips": 0.01, "per_view": []},
                                "correspondence": None}))


def test_correspondence_regions_table_means_per_subject_and_method(run_dir):
    for s in ("S01", "S02"):
        for e, base in ((E1, 1.0), (E2, 3.0)):
            add_regions(run_dir, s, "gpja", e, base if s == "S01" else base + 2)
            add_regions(run_dir, s, "nicp", e, 0.5)
    run = load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    table = correspondence_regions_table(run)
    rows = {(r["subject"], r["method"], r["region"]): r for r in read_csv_rows(to_csv(table))}
    assert float(rows[("S01", "gpja", "mouth")]["median_mm"]) == pytest.approx(2.0)  # (1 + 3) / 2
    assert float(rows[("S01", "gpja", "eyes")]["mean_mm"]) == pytest.approx(3.5)
    assert float(rows[("Average", "gpja", "mouth")]["median_mm"]) == pytest.approx(3.0)  # (2 + 4) / 2
    assert rows[("S01", "gpja", "brows")]["median_mm"] == "" and rows[("S01", "gpja", "brows")]["expressions"] == "0"
    md = to_markdown(table)
    assert md_row(md, "Subject S01")[:5] == ["GPJA", "2.000", "2.500", "3.000", "3.500"]
    assert "mouth/lips Median (mm) ↓" in md and "ears/scalp/neck Mean (mm) ↓" in md
    # the tables that need them appear by default only when the JSONs have them
    assert "correspondence_regions" in T.default_tables(run)
    bare = load_run(run_dir, ["S01"], ["nphm"], [E1])
    assert "correspondence_regions" not in T.default_tables(bare)
    with pytest.raises(InputError, match="no per-region correspondence scores"):
        correspondence_regions_table(bare)


def test_the_oracle_is_a_group_of_table_2_and_in_no_other_table(run_dir, tmp_path):
    for s, psnr in (("S01", 40.0), ("S02", 42.0)):
        for e in (E1, E2):
            write_oracle(run_dir, s, e, psnr)
    tables = T.build_tables(run_dir, tmp_path, ["S01", "S02"], ["gpja", "nicp", "oracle"], [E1, E2],
                            names=["geometry", "photometric", "correspondence"])
    geometry, photometric, correspondence = tables
    assert "Oracle" not in to_markdown(geometry) and "Oracle" not in to_markdown(correspondence)
    md = to_markdown(photometric)
    assert md_row(md, "Average")[-3:] == ["41.00", "0.9900", "0.01000"] and "Oracle (ground truth)" in md
    assert "the best any method can score here" in md
    rows = {(r["subject"], r["method"]): r for r in read_csv_rows(to_csv(photometric))}
    assert rows[("S02", "oracle")]["source"] == "reference" and rows[("S02", "oracle")]["expressions"] == "2"
    # the regression reference keeps the oracle's scores (photometric only) and checks them
    reference = tmp_path / "reference.json"
    assert write_reference(run_dir, reference, methods=["oracle"]) == 4
    assert check_regression(run_dir, reference) == ([], 12)


def test_the_oracles_true_surface_is_an_unbolded_row_of_table_1(run_dir, tmp_path):
    for s, cd, nc in (("S01", 0.1, 0.94), ("S02", 0.0, 1.0)):  # S01's scan noisy, S02's not
        for e in (E1, E2):
            write_oracle(run_dir, s, e, 40.0, cd, nc)
    geometry, photometric = T.build_tables(run_dir, tmp_path, ["S01", "S02"], ["gpja", "nicp", "oracle"], [E1, E2],
                                           names=["geometry", "photometric"])
    md = to_markdown(geometry)
    # S01 C.D., N.C. | S02 | Average; the oracle's better scores are not bolded, GPJA's stay the best of the methods
    assert md_row(md, "Oracle (ground truth)")[:6] == ["0.100", "0.940", "0.000", "1.000", "0.050", "0.970"]
    assert md_row(md, "GPJA")[:2] == ["**0.200**", "**0.980**"]
    assert "what the scan's noise alone costs" in md
    rows = {(r["subject"], r["method"]): r for r in read_csv_rows(to_csv(geometry))}
    assert rows[("Average", "oracle")]["source"] == "reference" and rows[("Average", "oracle")]["expressions"] == "4"
    assert float(rows[("Average", "oracle")]["normal_consistency"]) == pytest.approx(0.97)
    assert "Oracle (ground truth)" in to_markdown(photometric)


def write_quality(results, subject, psnr_observed, psnr_unobserved):
    path = Layout(results).template_file(subject, "texture_quality.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"observed": {"psnr": psnr_observed, "ssim": 0.9, "texels": 100},
                                "unobserved": {"psnr": psnr_unobserved, "ssim": 0.7, "texels": 20},
                                "gain": [1.0, 0.98, 1.02], "observed_source": "texture_observed.png"}))


def test_texture_table_per_subject_and_average(run_dir, tmp_path, capsys):
    write_quality(run_dir, "S01", 32.0, 25.0)
    write_quality(run_dir, "S02", 34.0, None)
    table = texture_table(run_dir, ["S01", "S02"])
    md = to_markdown(table)
    assert md_row(md, "Subject S01") == ["32.00", "0.9000", "25.00", "0.7000", "1.000", "0.980", "1.020", "100", "20"]
    assert md_row(md, "Average")[:4] == ["33.00", "0.9000", "25.00", "0.7000"]
    rows = {r["subject"]: r for r in read_csv_rows(to_csv(table))}
    assert rows["S02"]["psnr_unobserved"] == "" and rows["S01"]["observed_source"] == "texture_observed.png"
    run = load_run(run_dir, ["S01", "S02"], ["gpja"], [E1])
    assert "texture" in T.default_tables(run, results=run_dir) and "texture" not in T.default_tables(run)
    Layout(run_dir).template_file("S02", "texture_quality.json").unlink()
    with pytest.raises(InputError, match="texture_quality.json: missing: texture quality of subject S02"):
        texture_table(run_dir, ["S01", "S02"])
    assert "texture" not in T.default_tables(run, results=run_dir)
    argv = ["tables", "--results", str(run_dir), "--benchmarks", str(tmp_path), "--subjects", "S01",
            "--expressions", E1, "--methods", "gpja", "--tables", "texture", "--output-dir", str(tmp_path / "t")]
    assert main(argv) == 0 and (tmp_path / "t" / "texture.tex").is_file()


def test_a_reference_record_without_photometry_is_rejected(tmp_path):
    path = Layout(tmp_path).metrics("S01", "oracle", E1)
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({"method": "oracle", "geometry": None, "photometric": None}))
    with pytest.raises(InputError, match="a reference's metrics need photometric numbers"):
        load_run(tmp_path, ["S01"], ["oracle"], [E1])
    write_metrics(tmp_path, "S01", "gpja", E1, cd=0.1)
    record = json.loads(Layout(tmp_path).metrics("S01", "gpja", E1).read_text())
    record["geometry"] = None  # a method's record still needs its geometry
    Layout(tmp_path).metrics("S01", "gpja", E1).write_text(json.dumps(record))
    with pytest.raises(InputError, match="no 'geometry' section"):
        load_run(tmp_path, ["S01"], ["gpja"], [E1])
