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
    # 2 pairs: mean ± sample SD, the mean bolded
    assert md_row(md, "GPJA") == ["**0.050 ± 0.000**", "**0.100 ± 0.000**", "25.00 ± 0.00", "**0.8000 ± 0.0000**",
                                  "**0.10000 ± 0.00000**"]
    assert md_row(md, "w/o L_normal") == ["0.200 ± 0.000", "0.400 ± 0.141", "**26.00 ± 0.00**", "0.7900 ± 0.0000",
                                          "0.12000 ± 0.00000"]
    assert r"w/o $\mathcal{L}_{normal}$ & 0.200 $\pm$ 0.000" in to_latex(table)
    rows = read_csv_rows(to_csv(table))
    assert [r["method"] for r in rows if r["source"] == "reproduced"] == ["gpja", "gpja-no_normal"]
    assert T.default_tables(run) == ["geometry", "photometric", "ablation", "timing"]
    assert T.comparison_methods(run.methods) == ["gpja"]
    # the caption names the variants this run has, and only those
    assert "GPJA and its variants (w/o L_normal), and each variant's paired differences" in table.caption
    assert "no_flow" not in table.caption and "paper" not in table.caption
    alone = T.ablation_table(load_run(res, ["S01", "S02"], ["gpja"], [E1]))
    assert alone.caption.endswith("SSIM and LPIPS of GPJA.")


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


E3 = "3_mouth_open"


def write_ablation(res, gpja: dict, variant: dict, method: str = "gpja-no_normal", subject: str = "S01"):
    """GPJA's and ``method``'s metrics per expression: ``{expression: (C.D. mm, PSNR dB)}`` (SSIM, LPIPS fixed)."""
    for name, values in (("gpja", gpja), (method, variant)):
        for e, (cd, psnr) in values.items():
            write_metrics(res, subject, name, e, cd=cd, photo=(psnr, 0.8, 0.1))


def test_ablation_table_sd_and_paired_differences_analytic(tmp_path):
    res = tmp_path / "results"
    # C.D. differences 0.05, 0.15, 0.10 (mean 0.10, GPJA lower on all 3); PSNR differences +1, -1, +1 (mean 1/3,
    # GPJA higher on 1)
    write_ablation(res, {E1: (0.10, 24.0), E2: (0.20, 25.0), E3: (0.30, 26.0)},
                   {E1: (0.15, 25.0), E2: (0.35, 24.0), E3: (0.40, 27.0)})
    run = load_run(res, ["S01"], ["gpja", "gpja-no_normal"], [E1, E2, E3])
    table = T.ablation_table(run)
    md = to_markdown(table)
    # SDs by hand: GPJA C.D. 0.1, PSNR 1; the variant's C.D. sqrt((0.15² + 0.05² + 0.1²) / 2) = sqrt(0.0175),
    # PSNR sqrt(((1/3)² + (4/3)² + (5/3)²) / 2) = sqrt(7/3)
    assert md_row(md, "GPJA") == ["**0.200 ± 0.100**", "**0.200 ± 0.100**", "25.00 ± 1.00", "**0.8000 ± 0.0000**",
                                  "**0.10000 ± 0.00000**"]
    assert md_row(md, "w/o L_normal") == ["0.300 ± 0.132", "0.300 ± 0.132", "**25.33 ± 1.53**",
                                          "**0.8000 ± 0.0000**", "**0.10000 ± 0.00000**"]
    assert "*Paired differences against full GPJA*" in md
    cd_row, psnr_row = md_row(md, "w/o L_normal", 1), md_row(md, "w/o L_normal", 2)
    assert cd_row[:2] == ["C.D. (mm) ↓", "+0.100"] and cd_row[3] == "3 of 3"
    assert psnr_row[:2] == ["PSNR (dB) ↑", "+0.33"] and psnr_row[3] == "1 of 3"
    rows = read_csv_rows(to_csv(table))
    means = {r["method"]: r for r in rows if r["source"] == "reproduced"}
    assert float(means["gpja"]["chamfer_l1_mm"]) == pytest.approx(0.2)
    assert float(means["gpja"]["chamfer_l1_mm_sd"]) == pytest.approx(0.1)
    assert float(means["gpja-no_normal"]["chamfer_l1_mm_sd"]) == pytest.approx(0.0175 ** 0.5)
    assert float(means["gpja-no_normal"]["psnr_sd"]) == pytest.approx((7 / 3) ** 0.5)
    assert means["gpja"]["expressions"] == "3" and means["gpja"]["metric"] == ""
    paired = {r["metric"]: r for r in rows if r["source"] == "paired_difference"}
    assert list(paired) == ["chamfer_l1_mm", "psnr"]  # no correspondence scores here
    for name, diffs, better in (("chamfer_l1_mm", [0.05, 0.15, 0.10], 3), ("psnr", [1.0, -1.0, 1.0], 1)):
        row = paired[name]
        mean = sum(diffs) / 3
        assert row["method"] == "gpja-no_normal" and row[name] == ""
        assert float(row["mean_difference"]) == pytest.approx(mean)
        assert (row["gpja_better"], row["pairs"]) == (str(better), "3")
        low, high = float(row["ci_low"]), float(row["ci_high"])
        assert min(diffs) - 1e-12 <= low <= mean <= high <= max(diffs) + 1e-12
        assert low < high
    assert "[" + f"{float(paired['chamfer_l1_mm']['ci_low']):+.3f}" in cd_row[2]
    assert any("sample standard deviation" in n for n in table.notes)
    assert any("bootstrap" in n and "2000 resamples" in n for n in table.notes)
    assert any("fewer than about 5 pairs (here 3)" in n for n in table.notes)
    tex = to_latex(table)
    assert r"\textbf{0.200 $\pm$ 0.100}" in tex and r"& +0.100 & [" in tex
    assert tex.count(r"\begin{tabular}{lccccc}") == 1


def test_paired_statistics_functions():
    variant = [{"psnr": 25.0}, {"psnr": 24.0}, {"psnr": None}, {"psnr": 27.0}]
    reference = [{"psnr": 24.0}, {"psnr": 25.0}, {"psnr": 20.0}, {}]
    assert T.paired_differences(variant, reference, "psnr").tolist() == [1.0, -1.0]  # pairs both scored
    assert T.wins([1.0, -1.0, 0.0, 2.0], "max") == 1 and T.wins([1.0, -1.0, 0.0, 2.0], "min") == 2
    assert T.bootstrap_interval([0.4]) is None and T.bootstrap_interval([]) is None
    low, high = T.bootstrap_interval([0.0, 1.0, 2.0, 3.0])
    assert 0.0 <= low < 1.5 < high <= 3.0
    assert T.bootstrap_interval([0.0, 1.0, 2.0, 3.0]) == (low, high)  # seeded
    assert T.bootstrap_interval([0.0, 1.0, 2.0, 3.0], level=0.5)[1] < high


def test_ablation_table_identical_variant_has_zero_differences(tmp_path):
    res = tmp_path / "results"
    same = {E1: (0.10, 24.0), E2: (0.20, 25.0), E3: (0.30, 26.0)}
    write_ablation(res, same, same, method="gpja-no_depth")
    table = T.ablation_table(load_run(res, ["S01"], ["gpja", "gpja-no_depth"], [E1, E2, E3]))
    md = to_markdown(table)
    assert md_row(md, "w/o L_depth", 1) == ["C.D. (mm) ↓", "+0.000", "[+0.000, +0.000]", "0 of 3"]
    assert md_row(md, "w/o L_depth", 2) == ["PSNR (dB) ↑", "+0.00", "[+0.00, +0.00]", "0 of 3"]
    for row in (r for r in read_csv_rows(to_csv(table)) if r["source"] == "paired_difference"):
        assert (float(row["mean_difference"]), float(row["ci_low"]), float(row["ci_high"])) == (0.0, 0.0, 0.0)
        assert row["gpja_better"] == "0"


def test_ablation_table_is_deterministic(tmp_path):
    res = tmp_path / "results"
    write_ablation(res, {E1: (0.10, 24.0), E2: (0.20, 25.0), E3: (0.30, 26.0)},
                   {E1: (0.13, 25.0), E2: (0.35, 24.5), E3: (0.31, 27.0)}, method="gpja-paper")
    run = load_run(res, ["S01"], ["gpja", "gpja-paper"], [E1, E2, E3])
    first, second = T.ablation_table(run), T.ablation_table(run)
    assert to_csv(first) == to_csv(second)
    assert to_markdown(first) == to_markdown(second) and to_latex(first) == to_latex(second)


def test_ablation_table_with_one_pair_has_no_sd_and_no_interval(tmp_path):
    res = tmp_path / "results"
    write_ablation(res, {E1: (0.10, 24.0)}, {E1: (0.30, 23.0)})
    table = T.ablation_table(load_run(res, ["S01"], ["gpja", "gpja-no_normal"], [E1]))
    md = to_markdown(table)
    assert "±" not in "".join(line for line in md.splitlines() if line.startswith("|"))
    assert md_row(md, "GPJA")[:3] == ["**0.100**", "**0.100**", "**24.00**"]
    assert md_row(md, "w/o L_normal", 1) == ["C.D. (mm) ↓", "+0.200", "–", "1 of 1"]
    assert md_row(md, "w/o L_normal", 2) == ["PSNR (dB) ↑", "-1.00", "–", "1 of 1"]
    paired = [r for r in read_csv_rows(to_csv(table)) if r["source"] == "paired_difference"]
    assert [(r["ci_low"], r["ci_high"], r["pairs"]) for r in paired] == [("", "", "1")] * 2
    # GPJA alone: nothing to compare
    alone = T.ablation_table(load_run(res, ["S01"], ["gpja"], [E1]))
    assert len(alone.blocks) == 1 and "paired_difference" not in to_csv(alone)


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
