"""A :class:`~gpja.report.table_model.Table` as CSV (long format, full precision), Markdown and LaTeX.

CSV: one row per value row of the table, numbers at full precision (``repr``), a missing value empty.
Markdown: GitHub pipe tables, the caption bold, a block's title in italics when there are several, the
notes after. LaTeX: one booktabs ``table`` float (``\\usepackage{booktabs}``), blocks separated by rules, a block
narrower than the widest padded with empty cells.
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

from gpja.io import write_text
from gpja.report.table_model import DASH, Block, Cell, Label, Table, label_text
from gpja.results import TABLE_FORMATS

def md_label(label: Label) -> str:
    """Markdown text of a label (pipes escaped)."""
    return label_text(label).replace("|", "\\|")


def latex_escape(text: str) -> str:
    """Plain text as LaTeX: specials escaped, arrows and the dash made LaTeX."""
    specials = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
                "↓": r"$\downarrow$", "↑": r"$\uparrow$", "→": r"$\rightarrow$", "±": r"$\pm$", DASH: "--"}
    return "".join(specials.get(ch, ch) for ch in text)


def latex_label(label: Label) -> str:
    """LaTeX of a label: the given LaTeX of a pair, else the escaped text."""
    return label[1] if isinstance(label, tuple) else latex_escape(label)


def cell_markdown(item) -> str:
    if isinstance(item, Cell):
        return f"**{item.text()}**" if item.bold else item.text()
    return md_label(item)


def cell_latex(item) -> str:
    if isinstance(item, Cell):
        text = latex_escape(item.text())
        return rf"\textbf{{{text}}}" if item.bold else text
    return latex_label(item)


def flat_headers(block: Block) -> list[str]:
    """Markdown headers: a number column's group label prefixed (Markdown has no spanning header)."""
    groups = [md_label(label) for label, span in block.groups for _ in range(span)]
    labels = [md_label(h) for h in block.headers]
    if not groups:
        return labels
    return labels[:block.label_columns] + [f"{g} {h}" for g, h in zip(groups, labels[block.label_columns:])]


def markdown_block(block: Block) -> str:
    """One GitHub-flavoured pipe table."""
    align = [":---"] * block.label_columns + ["---:"] * (len(block.headers) - block.label_columns)
    lines = ["| " + " | ".join(flat_headers(block)) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(cell_markdown(c) for c in row) + " |" for row in block.rows]
    return "\n".join(lines) + "\n"


def to_markdown(table: Table) -> str:
    """The table as Markdown: caption, one pipe table per block (titled when several), notes."""
    parts = [f"**{table.caption}**\n"]
    for block in table.blocks:
        if block.title and len(table.blocks) > 1:
            parts.append(f"*{block.title}*\n")
        parts.append(markdown_block(block))
    parts += [note + "\n" for note in table.notes]
    return "\n".join(parts)


def latex_line(cells: list[str], columns: int) -> str:
    """One tabular line: ``cells``, then empty cells up to ``columns`` cells."""
    return " & ".join(cells + [""] * (columns - len(cells))) + r" \\"


def latex_block_header(block: Block, columns: int) -> list[str]:
    """The header line(s) of a block in a tabular of ``columns`` columns: spanning group labels with cmidrules,
    then the column headers."""
    lines = []
    if block.groups:
        cells, rules, col = [""] * block.label_columns, [], block.label_columns + 1
        for label, span in block.groups:
            cells.append(rf"\multicolumn{{{span}}}{{c}}{{{latex_label(label)}}}")
            rules.append(rf"\cmidrule(lr){{{col}-{col + span - 1}}}")
            col += span
        lines += [latex_line(cells, len(cells) + columns + 1 - col), " ".join(rules)]  # + columns after the groups
    lines.append(latex_line([latex_label(h) for h in block.headers], columns))
    return lines


def to_latex(table: Table) -> str:
    """The table as a booktabs ``table`` float (needs ``\\usepackage{booktabs}``); one tabular as wide as the widest
    block, its column types from the first block."""
    columns = max(len(b.headers) for b in table.blocks)
    first = table.blocks[0]
    spec = "l" * first.label_columns + "c" * (columns - first.label_columns)
    lines = [f"% {table.name}: written by `gpja tables` (gpja/report/tables.py)"]
    lines += [f"% {note}" for note in table.notes]
    lines += [r"\begin{table}[t]", r"\centering", rf"\caption{{{latex_escape(table.caption)}}}",
              rf"\label{{tab:gpja-{table.name}}}", rf"\begin{{tabular}}{{{spec}}}", r"\toprule"]
    for i, block in enumerate(table.blocks):
        if i:
            lines.append(r"\midrule")
        lines += latex_block_header(block, columns) + [r"\midrule"]
        for j, row in enumerate(block.rows):
            if j in block.rules:
                lines.append(r"\midrule")
            lines.append(latex_line([cell_latex(c) for c in row], columns))
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def csv_value(value) -> str:
    """A CSV field: full-precision numbers, empty for None."""
    if value is None:
        return ""
    return repr(float(value)) if isinstance(value, float) else str(value)


def to_csv(table: Table) -> str:
    """The table's long-format rows as CSV text."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(table.csv_header)
    writer.writerows([[csv_value(v) for v in row] for row in table.csv_rows])
    return out.getvalue()


def write_table(table: Table, out_dir: str | Path) -> list[Path]:
    """Write ``{out_dir}/{name}.csv``, ``.md`` and ``.tex`` atomically; return their paths."""
    texts = {"csv": to_csv(table), "md": to_markdown(table), "tex": to_latex(table)}
    paths = []
    for ext in TABLE_FORMATS:
        path = Path(out_dir) / f"{table.name}.{ext}"
        write_text(path, texts[ext])
        paths.append(path)
    return paths
