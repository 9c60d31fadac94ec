"""The table model every table is built in: cells, blocks and tables, bolding, labels and headers.

A :class:`Table` is a caption, one or more :class:`Block` (a header row and its rows, printed as one pipe
table in Markdown, one ``tabular`` section in LaTeX) and the long-format CSV rows; ``gpja.report.formats``
writes it. The best value of a column is bolded where the paper bolds (Tables 1 and 3); ties at the
printed precision are all bolded; rows of published numbers are never bolded.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from gpja.report.runs import AVERAGE, metric_family

#: A missing value, as printed.
DASH = "–"

# printed decimals per metric, as in the paper's tables
DIGITS = {"chamfer_l1_mm": 3, "mesh_to_scan_mm": 3, "scan_to_mesh_mm": 3, "normal_consistency": 3, "fscore": 3,
          "psnr": 2, "ssim": 4, "lpips": 5, "correspondence_mean_mm": 3, "correspondence_median_mm": 3,
          "correspondence_p95_mm": 3}
# which end of a metric is better
BETTER = {"chamfer_l1_mm": "min", "mesh_to_scan_mm": "min", "scan_to_mesh_mm": "min", "normal_consistency": "max",
          "fscore": "max", "psnr": "max", "ssim": "max", "lpips": "min", "correspondence_mean_mm": "min",
          "correspondence_median_mm": "min", "correspondence_p95_mm": "min"}
HEADERS = {"chamfer_l1_mm": "C.D. (mm) ↓", "mesh_to_scan_mm": "Mesh→scan (mm) ↓",
           "scan_to_mesh_mm": "Geometric error (mm) ↓", "normal_consistency": "N.C. ↑", "psnr": "PSNR (dB) ↑",
           "ssim": "SSIM ↑", "lpips": "LPIPS ↓", "correspondence_mean_mm": "Mean (mm) ↓",
           "correspondence_median_mm": "Median (mm) ↓", "correspondence_p95_mm": "P95 (mm) ↓"}


# a label is plain text (escaped for LaTeX) or a (markdown, latex) pair
Label = str | tuple[str, str]


@dataclass
class Cell:
    """A number printed with ``digits`` decimals ("–" for None), and with a spread ``sd`` (same unit) as
    ``value ± sd`` at the same decimals."""

    value: float | None
    digits: int
    bold: bool = False
    sd: float | None = None

    def number(self, value: float) -> str:
        """``value`` at this cell's decimals."""
        return f"{value:.{self.digits}f}"

    def printed(self) -> float:
        """The value as printed (rounded to ``digits``): what bolding compares."""
        return float(self.number(self.value))

    def text(self) -> str:
        if self.value is None:
            return DASH
        return self.number(self.value) if self.sd is None else f"{self.number(self.value)} ± {self.number(self.sd)}"


@dataclass
class Block:
    """One header and its rows: ``label_columns`` leading label columns, then number columns.

    ``groups``: spanning headers ``(label, span)`` over the number columns; ``rules``: row indices a
    horizontal rule is drawn before; ``reference_rows``: rows of published numbers (never bolded);
    ``better``: per column ``"min"``/``"max"`` (bold the best) or None.
    """

    headers: list[Label]
    rows: list[list]
    label_columns: int = 1
    groups: list[tuple[Label, int]] = field(default_factory=list)
    rules: set[int] = field(default_factory=set)
    reference_rows: set[int] = field(default_factory=set)
    better: list[str | None] = field(default_factory=list)
    title: str = ""


@dataclass
class Table:
    """A table's Markdown/LaTeX blocks and its long-format CSV."""

    name: str
    caption: str
    blocks: list[Block]
    csv_header: list[str]
    csv_rows: list[list]
    notes: list[str] = field(default_factory=list)


def mark_best(block: Block) -> None:
    """Bold the best printed value (the mean of a ``value ± sd`` cell) of each column with a ``better`` direction
    (ties all bolded)."""
    for col, better in enumerate(block.better):
        if better is None:
            continue
        cells = [row[col] for i, row in enumerate(block.rows)
                 if i not in block.reference_rows and isinstance(row[col], Cell) and row[col].value is not None]
        printed = [c.printed() for c in cells]
        if len(printed) < 2:
            continue
        best = min(printed) if better == "min" else max(printed)
        for cell, value in zip(cells, printed):
            cell.bold = value == best


def plural(n: int, noun: str) -> str:
    """``1 expression``, ``4 expressions``."""
    return f"{n} {noun}" + ("" if n == 1 else "s")


def metric_cell(value: float | None, name: str, sd: float | None = None) -> Cell:
    """A cell of metric ``name`` printed with the paper's decimals; with ``sd`` (its unit) as ``value ± sd``."""
    return Cell(value, DIGITS[metric_family(name)], sd=sd)


def header(name: str) -> str:
    """Column header of a metric, with its unit and the arrow of better."""
    if metric_family(name) == "fscore":
        threshold = float(name.split("@")[1])
        return f"F@{threshold:.1f} ↑" if threshold.is_integer() else f"F@{threshold:g} ↑"
    return HEADERS[name]


def label_text(label: Label) -> str:
    """The plain text of a label (the first of a (text, LaTeX) pair)."""
    return label[0] if isinstance(label, tuple) else label


def paper_label(label: Label) -> Label:
    """The label of a row or column of published numbers."""
    if isinstance(label, tuple):
        return (f"{label[0]} (paper)", f"{label[1]} (paper)")
    return f"{label} (paper)"


def subject_label(subject: str) -> str:
    """``7`` -> ``Subject 7``; the average keeps its name."""
    return subject if subject == AVERAGE else f"Subject {subject}"
