"""gpja.report.formats: a table written as CSV, Markdown and booktabs LaTeX."""
from __future__ import annotations

from gpja.report import tables as T
from gpja.report.formats import write_table
from gpja.report.runs import load_run
from tests.report import E1, E2, read_csv_rows


def test_files_are_written_as_csv_markdown_and_booktabs_latex(run_dir, tmp_path):
    run = load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    paths = write_table(T.geometry_table(run), tmp_path / "tables")
    assert [p.name for p in paths] == ["geometry.csv", "geometry.md", "geometry.tex"]
    assert all(p.is_file() for p in paths)
    assert len(read_csv_rows(paths[0].read_text())) == 2 * 3  # 2 methods x (2 subjects + average)
    tex = paths[2].read_text()
    for text in (r"\toprule", r"\midrule", r"\bottomrule", r"\cmidrule(lr){2-3}", r"\multicolumn{2}{c}{Subject S01}",
                 r"C.D. (mm) $\downarrow$", r"GPJA & \textbf{0.200} & \textbf{0.980}", r"\label{tab:gpja-geometry}"):
        assert text in tex
    assert tex.count(r"\begin{tabular}{lcccccc}") == 1
