"""Reporting: the paper's tables and figures from a finished run, and the CI regression check.

Tables (``gpja tables``):
    ``runs``         reading a run's metrics JSONs (checked, flattened) and the means over them
    ``published``    the paper's published numbers, printed beside the reproduced ones
    ``table_model``  cells, blocks and tables, bolding, labels and headers
    ``tables``       Table 1 (geometry), 2 (photometry), 3 (ablations), correspondence; ``build_tables``
    ``timing``       the timing table from Snakemake's benchmark TSVs and the registration logs
    ``formats``      a table as CSV, Markdown and LaTeX

Figures (``gpja figure``):
    ``figures``              the registry: name -> draw function, what it draws and reads, when it is drawn
    ``drawing``              output, panel grids, the frontal camera and one-view renders every figure uses
    ``figures_geometry``     template stages, scan-to-mesh error heatmaps, the normal ablation
    ``figures_photometry``   photometric errors, close-ups, the mask ablation
    ``figures_convergence``  the loss curves of the registration logs

``regression``: compares a run's metrics against committed reference values with tolerances stated in
one place. Method names and labels come from ``gpja.methods``, every path from ``gpja.results.Layout``.
"""
