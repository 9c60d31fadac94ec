"""The shipped configurations, as the workflow reads them: one home for the tests that load them.

Most files under ``config/`` are whole configurations; an overlay (``config/extended.yaml``) names only what it
changes and is read, as ``snakemake --configfile`` reads it, merged over ``config/config.yaml``
(``snakemake.utils.update_config``: nested sections key by key).
"""
from __future__ import annotations

from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
#: Whole configurations.
WHOLE = ["config.yaml", "ci.yaml", "facescape.yaml", "paper.yaml"]
#: Overlays merged over config/config.yaml.
OVERLAYS = ["extended.yaml"]
CONFIGS = WHOLE + OVERLAYS


def load_config(name: str) -> dict:
    """The configuration ``config/<name>`` as the workflow sees it (an overlay merged over config.yaml)."""
    text = yaml.safe_load((ROOT / "config" / name).read_text())
    if name not in OVERLAYS:
        return text
    from snakemake.utils import update_config

    merged = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    update_config(merged, text)
    return merged
