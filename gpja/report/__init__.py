"""Reporting: the paper's tables from the per-expression metrics JSONs, and the CI regression check.

``tables``: Table 1 (geometry), Table 2 (photometry), Table 3 (ablations),
timing and correspondence, each written as CSV, Markdown and LaTeX.
``regression``: compares a run's metrics against committed reference values
with tolerances stated in one place.
"""
