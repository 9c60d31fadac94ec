"""The paper's tables from tiny fake runs: exact means, the three formats, bolding, published numbers, errors."""
from __future__ import annotations

import csv
import io
import statistics

import pytest

from gpja.cli import main
from gpja.errors import InputError
from gpja.report import tables as T
from tests.report import write_benchmark, write_log, write_metrics

E1, E2 = "1_neutral", "2_smile"


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


def test_geometry_table_means_over_expressions_and_average_of_subjects(run_dir):
    run = T.load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    table = T.geometry_table(run)
    rows = {(r["subject"], r["method"]): r for r in read_csv_rows(T.to_csv(table))}
    assert float(rows[("S01", "gpja")]["chamfer_l1_mm"]) == pytest.approx(0.2)
    assert float(rows[("S02", "gpja")]["chamfer_l1_mm"]) == pytest.approx(0.3)
    assert float(rows[("Average", "gpja")]["chamfer_l1_mm"]) == pytest.approx(0.25)
    assert float(rows[("Average", "nicp")]["normal_consistency"]) == pytest.approx(0.955)
    assert float(rows[("S01", "nicp")]["fscore@0.5"]) == pytest.approx(0.7)
    assert rows[("S01", "gpja")]["expressions"] == "2" and rows[("Average", "gpja")]["expressions"] == "4"
    md = T.to_markdown(table)
    # block 1: per subject C.D., N.C.; S01 | S02 | Average; best bolded per column
    assert md_row(md, "GPJA")[:6] == ["**0.200**", "**0.980**", "**0.300**", "0.980", "**0.250**", "**0.980**"]
    assert md_row(md, "NICP")[:6] == ["0.600", "0.920", "0.500", "**0.990**", "0.550", "0.955"]
    assert "Subject S01 C.D. (mm) ↓" in md and "Average F@1.0 ↑" in md


def test_bold_ties_at_printed_precision_and_no_bold_for_a_single_method(run_dir):
    run = T.load_run(run_dir, ["S01"], ["gpja", "nicp"], [E1, E2])
    md = T.to_markdown(T.geometry_table(run))
    # F@0.5 / F@1.0 block: gpja wins both; S01 and Average columns
    assert md_row(md, "GPJA", 1) == ["**0.900**", "**0.960**", "**0.900**", "**0.960**"]
    block = T.Block(["M", "x"], [["a", T.Cell(0.1004, 3)], ["b", T.Cell(0.0996, 3)], ["c", T.Cell(0.2, 3)]],
                    better=[None, "min"])
    T.mark_best(block)
    assert [r[1].bold for r in block.rows] == [True, True, False]
    alone = T.to_markdown(T.geometry_table(T.load_run(run_dir, ["S01"], ["gpja"], [E1])))
    assert "**" not in alone.split("\n", 1)[1]  # only the caption is bold


def test_photometric_table_and_methods_without_uvs_shown_as_dash(run_dir):
    run = T.load_run(run_dir, ["S01", "S02"], ["gpja", "nphm"], [E1, E2])
    table = T.photometric_table(run)
    md = T.to_markdown(table)
    assert md_row(md, "Subject S01") == ["25.00", "0.7600", "0.09000", "–", "–", "–"]
    assert md_row(md, "Average") == ["25.00", "0.7600", "0.09000", "–", "–", "–"]
    assert "no photometric scores" in md
    rows = {(r["subject"], r["method"]): r for r in read_csv_rows(T.to_csv(table))}
    assert float(rows[("Average", "gpja")]["lpips"]) == pytest.approx(0.09)
    assert rows[("S01", "nphm")]["psnr"] == "" and rows[("S01", "nphm")]["expressions"] == "0"
    tex = T.to_latex(table)
    assert r"\multicolumn{3}{c}{GPJA} & \multicolumn{3}{c}{nphm}" in tex and "-- & -- & --" in tex


def test_files_are_written_as_csv_markdown_and_booktabs_latex(run_dir, tmp_path):
    run = T.load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    paths = T.write_table(T.geometry_table(run), tmp_path / "tables")
    assert [p.name for p in paths] == ["geometry.csv", "geometry.md", "geometry.tex"]
    assert all(p.is_file() for p in paths)
    assert len(read_csv_rows(paths[0].read_text())) == 2 * 3  # 2 methods x (2 subjects + average)
    tex = paths[2].read_text()
    for text in (r"\toprule", r"\midrule", r"\bottomrule", r"\cmidrule(lr){2-3}", r"\multicolumn{2}{c}{Subject S01}",
                 r"C.D. (mm) $\downarrow$", r"GPJA & \textbf{0.200} & \textbf{0.980}", r"\label{tab:gpja-geometry}"):
        assert text in tex
    assert tex.count(r"\begin{tabular}{lcccccc}") == 1


def test_missing_metrics_file_names_it(run_dir):
    with pytest.raises(InputError) as err:
        T.load_run(run_dir, ["S01", "S03"], ["gpja"], [E1])
    assert str(run_dir / "S03/gpja/metrics/1_neutral.json") in str(err.value)
    assert "subject S03, method gpja, expression 1_neutral" in str(err.value)
    (run_dir / "S01/gpja/metrics/1_neutral.json").write_text('{"geometry": {"chamfer_l1_mm": 1}}')
    with pytest.raises(InputError, match="geometry.mesh_to_scan_mm"):
        T.load_run(run_dir, ["S01"], ["gpja"], [E1])


def test_ablation_table_means_bolding_and_labels(tmp_path):
    res = tmp_path / "results"
    for s in ("S01", "S02"):
        write_metrics(res, s, "gpja", E1, cd=0.1, p2m=0.05, photo=(25.0, 0.80, 0.10))
        write_metrics(res, s, "gpja-no_normal", E1, cd=0.3 if s == "S01" else 0.5, p2m=0.2, photo=(26.0, 0.79, 0.12))
    run = T.load_run(res, ["S01", "S02"], ["gpja-no_normal", "gpja"], [E1])
    table = T.ablation_table(run)
    md = T.to_markdown(table)
    assert md_row(md, "GPJA") == ["**0.050**", "**0.100**", "25.00", "**0.8000**", "**0.10000**"]
    assert md_row(md, "w/o L_normal") == ["0.200", "0.400", "**26.00**", "0.7900", "0.12000"]
    assert r"w/o $\mathcal{L}_{normal}$ & 0.200" in T.to_latex(table)
    assert [r["method"] for r in read_csv_rows(T.to_csv(table))] == ["gpja", "gpja-no_normal"]
    assert T.default_tables(run) == ["geometry", "photometric", "ablation", "timing"]
    assert T.comparison_methods(run.methods) == ["gpja"]


def test_published_facescape_numbers_beside_the_reproduced_ones(tmp_path):
    res = tmp_path / "results"
    for s in ("7", "32"):
        write_metrics(res, s, "gpja", E1, cd=0.2, nc=0.99, f05=0.95, f1=0.97, p2m=0.1, photo=(24.0, 0.75, 0.07))
    run = T.load_run(res, ["7", "32"], ["gpja"], [E1])
    md = T.to_markdown(T.geometry_table(run, "facescape"))
    # paper rows: subject 7, subject 32, and their mean; never bolded
    assert md_row(md, "NICP (paper)")[:6] == ["0.477", "0.910", "0.355", "0.942", "0.416", "0.926"]
    assert md_row(md, "GPJA (paper)")[:2] == ["0.229", "0.981"]
    photo = T.to_markdown(T.photometric_table(run, "facescape"))
    assert md_row(photo, "Subject 7") == ["24.00", "0.7500", "0.07000", "24.75", "0.7810", "0.06868"]
    assert "GPJA (paper) PSNR (dB) ↑" in photo
    ablation = T.to_markdown(T.ablation_table(run, "facescape"))
    assert md_row(ablation, "GPJA (paper)") == ["0.167", "–", "24.06", "0.7523", "0.07511"]
    assert md_row(ablation, "w/o L_color (paper)")[0] == "0.447"
    other = T.to_markdown(T.geometry_table(T.load_run(res, ["7"], ["gpja"], [E1]), "facescape"))
    assert md_row(other, "NPHM (paper)")[:4] == ["0.347", "0.958", "0.347", "0.958"]


def test_transcribed_paper_tables_agree_with_the_paper_average_row():
    for label, average in T.PUBLISHED_PHOTOMETRIC_AVERAGE.items():
        rows = T.PUBLISHED_PHOTOMETRIC[label].values()
        for i, digits in enumerate((2, 4, 5)):
            assert round(statistics.fmean(r[i] for r in rows), digits) == pytest.approx(average[i])
    assert all(len(per) == 7 for per in T.PUBLISHED_GEOMETRY.values())
    assert T.paper_subject("007") == "7" and T.paper_subject("S01") == "S01"


def test_correspondence_table_and_its_absence(run_dir):
    run = T.load_run(run_dir, ["S01", "S02"], ["gpja", "nicp", "nphm"], [E1, E2])
    md = T.to_markdown(T.correspondence_table(run))
    rows = [line for line in md.splitlines() if line.startswith("| Average")]
    assert rows == ["| Average | GPJA | 1.000 | 0.500 | 3.000 |", "| Average | NICP | 2.000 | 1.000 | 5.000 |",
                    "| Average | nphm | – | – | – |"]
    assert "correspondence" in T.default_tables(run)
    with pytest.raises(InputError, match="no correspondence scores"):
        T.correspondence_table(T.load_run(run_dir, ["S01"], ["nphm"], [E1]))


def test_timing_table_from_benchmarks_and_registration_logs(run_dir, tmp_path):
    bench = tmp_path / "benchmarks"
    for s, seconds in (("S01", 10.0), ("S02", 30.0)):
        write_benchmark(bench / s / "build_template.tsv", seconds, 500.0)
        write_benchmark(bench / s / "check_expression" / f"{E1}.tsv", 1.0, "NA")
        for i, e in enumerate((E1, E2)):
            write_benchmark(bench / s / "gpja" / f"{e}.tsv", seconds + i, 900.0 + i)
            write_benchmark(bench / s / "gpja" / "metrics" / f"{e}.tsv", 5.0, 100.0)
            write_log(run_dir, s, "gpja", e, {"seconds": seconds, "levels": [
                {"vertices": 100, "seconds": 2.0}, {"vertices": 400, "seconds": seconds - 2.0}]})
            write_log(run_dir, s, "nicp", e, {"vertices": 100, "seconds": {"total": 4.0}})
    write_benchmark(bench / "S01" / "old_method" / "metrics" / f"{E1}.tsv", 99.0, 1.0)  # not requested: left out
    run = T.load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    table = T.timing_table(run_dir, bench, run)
    rows = {(r["step"], r["source"]): r for r in read_csv_rows(T.to_csv(table))}
    assert list(rows) == [("check_expression", "benchmark"), ("build_template", "benchmark"),
                          ("GPJA registration", "benchmark"), ("GPJA optimisation", "log"), ("GPJA level 0", "log"),
                          ("GPJA level 1", "log"), ("GPJA metrics", "benchmark"), ("NICP optimisation", "log")]
    reg = rows[("GPJA registration", "benchmark")]
    assert reg["jobs"] == "4"
    assert (float(reg["median_s"]), float(reg["max_s"]), float(reg["max_rss_mb"])) == (20.5, 31.0, 901.0)
    assert rows[("check_expression", "benchmark")]["max_rss_mb"] == ""
    assert float(rows[("GPJA level 1", "log")]["vertices"]) == 400
    assert float(rows[("GPJA optimisation", "log")]["median_s"]) == 20
    assert md_row(T.to_markdown(table), "build_template") == ["benchmark", "2", "20.0", "30.0", "500", "–"]
    (run_dir / "S02/nicp/2_smile.json").unlink()
    with pytest.raises(InputError, match="registration log of subject S02, method nicp"):
        T.timing_table(run_dir, bench, run)


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
