"""The paper's tables from tiny fake runs: exact means, bolding, published numbers, errors, the CLI."""
from __future__ import annotations

import pytest

from gpja.cli import main
from gpja.errors import InputError
from gpja.report import tables as T
from gpja.report.formats import to_csv, to_latex, to_markdown
from gpja.report.runs import load_run
from tests.report import E1, E2, md_row, read_csv_rows, write_metrics


def test_geometry_table_means_over_expressions_and_average_of_subjects(run_dir):
    run = load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    table = T.geometry_table(run)
    rows = {(r["subject"], r["method"]): r for r in read_csv_rows(to_csv(table))}
    assert float(rows[("S01", "gpja")]["chamfer_l1_mm"]) == pytest.approx(0.2)
    assert float(rows[("S02", "gpja")]["chamfer_l1_mm"]) == pytest.approx(0.3)
    assert float(rows[("Average", "gpja")]["chamfer_l1_mm"]) == pytest.approx(0.25)
    assert float(rows[("Average", "nicp")]["normal_consistency"]) == pytest.approx(0.955)
    assert float(rows[("S01", "nicp")]["fscore@0.5"]) == pytest.approx(0.7)
    assert rows[("S01", "gpja")]["expressions"] == "2" and rows[("Average", "gpja")]["expressions"] == "4"
    md = to_markdown(table)
    # block 1: per subject C.D., N.C.; S01 | S02 | Average; best bolded per column
    assert md_row(md, "GPJA")[:6] == ["**0.200**", "**0.980**", "**0.300**", "0.980", "**0.250**", "**0.980**"]
    assert md_row(md, "NICP")[:6] == ["0.600", "0.920", "0.500", "**0.990**", "0.550", "0.955"]
    assert "Subject S01 C.D. (mm) ↓" in md and "Average F@1.0 ↑" in md


def test_bold_ties_at_printed_precision_and_no_bold_for_a_single_method(run_dir):
    run = load_run(run_dir, ["S01"], ["gpja", "nicp"], [E1, E2])
    md = to_markdown(T.geometry_table(run))
    # F@0.5 / F@1.0 block: gpja wins both; S01 and Average columns
    assert md_row(md, "GPJA", 1) == ["**0.900**", "**0.960**", "**0.900**", "**0.960**"]
    alone = to_markdown(T.geometry_table(load_run(run_dir, ["S01"], ["gpja"], [E1])))
    assert "**" not in alone.split("\n", 1)[1]  # only the caption is bold


def test_photometric_table_and_methods_without_uvs_shown_as_dash(run_dir):
    run = load_run(run_dir, ["S01", "S02"], ["gpja", "nphm"], [E1, E2])
    table = T.photometric_table(run)
    md = to_markdown(table)
    assert md_row(md, "Subject S01") == ["25.00", "0.7600", "0.09000", "–", "–", "–"]
    assert md_row(md, "Average") == ["25.00", "0.7600", "0.09000", "–", "–", "–"]
    assert "no photometric scores" in md
    rows = {(r["subject"], r["method"]): r for r in read_csv_rows(to_csv(table))}
    assert float(rows[("Average", "gpja")]["lpips"]) == pytest.approx(0.09)
    assert rows[("S01", "nphm")]["psnr"] == "" and rows[("S01", "nphm")]["expressions"] == "0"
    tex = to_latex(table)
    assert r"\multicolumn{3}{c}{GPJA} & \multicolumn{3}{c}{nphm}" in tex and "-- & -- & --" in tex


def test_ablation_table_means_bolding_and_labels(tmp_path):
    res = tmp_path / "results"
    for s in ("S01", "S02"):
        write_metrics(res, s, "gpja", E1, cd=0.1, p2m=0.05, photo=(25.0, 0.80, 0.10))
        write_metrics(res, s, "gpja-no_normal", E1, cd=0.3 if s == "S01" else 0.5, p2m=0.2, photo=(26.0, 0.79, 0.12))
    run = load_run(res, ["S01", "S02"], ["gpja-no_normal", "gpja"], [E1])
    table = T.ablation_table(run)
    md = to_markdown(table)
    assert md_row(md, "GPJA") == ["**0.050**", "**0.100**", "25.00", "**0.8000**", "**0.10000**"]
    assert md_row(md, "w/o L_normal") == ["0.200", "0.400", "**26.00**", "0.7900", "0.12000"]
    assert r"w/o $\mathcal{L}_{normal}$ & 0.200" in to_latex(table)
    assert [r["method"] for r in read_csv_rows(to_csv(table))] == ["gpja", "gpja-no_normal"]
    assert T.default_tables(run) == ["geometry", "photometric", "ablation", "timing"]
    assert T.comparison_methods(run.methods) == ["gpja"]


def test_ablation_table_gains_correspondence_columns_on_synthetic_data(tmp_path):
    res = tmp_path / "results"
    write_metrics(res, "S01", "gpja", E1, cd=0.1, p2m=0.05, photo=(25.0, 0.80, 0.10), corr=(1.5, 0.4, 6.0))
    write_metrics(res, "S01", "gpja-paper", E1, cd=0.4, p2m=0.3, photo=(23.0, 0.70, 0.20), corr=(3.1, 0.35, 13.0))
    md = to_markdown(T.ablation_table(load_run(res, ["S01"], ["gpja", "gpja-paper"], [E1])))
    assert "Corr. median (mm)" in md and "Corr. mean (mm)" in md
    assert md_row(md, "GPJA")[-2:] == ["0.400", "**1.500**"]
    assert md_row(md, "GPJA (paper schedule)")[-2:] == ["**0.350**", "3.100"]
    # without ground truth there is nothing to show
    plain = tmp_path / "plain"
    write_metrics(plain, "S01", "gpja", E1, cd=0.1, p2m=0.05, photo=(25.0, 0.80, 0.10))
    assert "Corr." not in to_markdown(T.ablation_table(load_run(plain, ["S01"], ["gpja"], [E1])))


def test_published_facescape_numbers_beside_the_reproduced_ones(tmp_path):
    res = tmp_path / "results"
    for s in ("7", "32"):
        write_metrics(res, s, "gpja", E1, cd=0.2, nc=0.99, f05=0.95, f1=0.97, p2m=0.1, photo=(24.0, 0.75, 0.07))
    run = load_run(res, ["7", "32"], ["gpja"], [E1])
    md = to_markdown(T.geometry_table(run, "facescape"))
    # paper rows: subject 7, subject 32, and their mean; never bolded
    assert md_row(md, "NICP (paper)")[:6] == ["0.477", "0.910", "0.355", "0.942", "0.416", "0.926"]
    assert md_row(md, "GPJA (paper)")[:2] == ["0.229", "0.981"]
    photo = to_markdown(T.photometric_table(run, "facescape"))
    assert md_row(photo, "Subject 7") == ["24.00", "0.7500", "0.07000", "24.75", "0.7810", "0.06868"]
    assert "GPJA (paper) PSNR (dB) ↑" in photo
    ablation = to_markdown(T.ablation_table(run, "facescape"))
    assert md_row(ablation, "GPJA (paper)") == ["0.167", "–", "24.06", "0.7523", "0.07511"]
    assert md_row(ablation, "w/o L_color (paper)")[0] == "0.447"
    other = to_markdown(T.geometry_table(load_run(res, ["7"], ["gpja"], [E1]), "facescape"))
    assert md_row(other, "NPHM (paper)")[:4] == ["0.347", "0.958", "0.347", "0.958"]


def test_correspondence_table_and_its_absence(run_dir):
    run = load_run(run_dir, ["S01", "S02"], ["gpja", "nicp", "nphm"], [E1, E2])
    md = to_markdown(T.correspondence_table(run))
    rows = [line for line in md.splitlines() if line.startswith("| Average")]
    assert rows == ["| Average | GPJA | 1.000 | 0.500 | 3.000 |", "| Average | NICP | 2.000 | 1.000 | 5.000 |",
                    "| Average | nphm | – | – | – |"]
    assert "correspondence" in T.default_tables(run)
    with pytest.raises(InputError, match="no correspondence scores"):
        T.correspondence_table(load_run(run_dir, ["S01"], ["nphm"], [E1]))


def test_cli_writes_the_requested_tables(run_dir, tmp_path, capsys):
    out = tmp_path / "tables"
    argv = ["tables", "--results", str(run_dir), "--benchmarks", str(tmp_path / "none"), "--subjects", "S01", "S02",
            "--expressions", E1, E2, "--methods", "gpja", "nphm", "--tables", "geometry", "photometric",
            "--output-dir", str(out)]
    assert main(argv) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(f"{t}.{x}" for t in ("geometry", "photometric")
                                                           for x in ("csv", "md", "tex"))
    assert main(argv[:-2] + ["--subjects", "S09", "--output-dir", str(out)]) == 2
    assert "S09/gpja/metrics/1_neutral.json: missing" in capsys.readouterr().err
