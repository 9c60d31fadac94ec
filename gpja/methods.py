"""The one registry of methods: GPJA, its ablation variants, the baselines and imported meshes.

The Snakemake rules (which methods run, with which switches), the CLI (``gpja register --method``,
``gpja baseline``), the tables (labels, which rows go in which table) and the figures read this
registry; nothing else lists method names.

Adding a baseline is one module with a ``run_baseline`` function (see
:func:`gpja.baselines.nicp.run_baseline` for the signature) plus one :class:`Method` entry in
:data:`METHODS` with ``kind="baseline"`` and ``entry`` naming that function. Its config section is
``baselines.<name>`` (``enabled`` plus whatever the module reads).
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable, Mapping

from gpja.errors import InputError

#: The constraints an ablation variant can switch off (paper Table 3), in table order.
CONSTRAINTS = ("normal", "depth", "color", "mask")
#: Kinds of method: the method under test, one of its ablation variants, a baseline run by the
#: workflow, a mesh made by another tool and imported (``baselines.external``), and a reference that
#: is no registration: a bound the methods are measured against (the oracle: the synthetic ground
#: truth rendered and scored photometrically, ``gpja.metrics.oracle``; Table 2 only).
KINDS = ("gpja", "ablation", "baseline", "imported", "reference")


@dataclass(frozen=True)
class Method:
    """One method the workflow can produce meshes with.

    Attributes:
        name: the name in paths and configs (``results/{dataset}/{subject}/{name}/``).
        label: display name in tables and figures.
        kind: one of :data:`KINDS`.
        without: the constraints switched off (ablation variants; empty otherwise).
        entry: ``"module:function"`` that runs a baseline (kind ``baseline`` only).
        schedule: the ``registration`` config section a GPJA registration takes its schedule from
            (``gpja``; ``paper`` for the paper's own schedule, ``no_flow`` for GPJA without the flow stage).
        overrides: ``(key, value)`` pairs that replace the section's values (``gpja-no_hold``: GPJA's own
            schedule with the tangential hold off), so a variant that differs in one setting names only it.
    """

    name: str
    label: str
    kind: str
    without: tuple[str, ...] = ()
    entry: str | None = None
    schedule: str = "gpja"
    overrides: tuple[tuple[str, object], ...] = ()

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"method {self.name!r}: kind {self.kind!r} is not one of {KINDS}")
        unknown = set(self.without) - set(CONSTRAINTS)
        if unknown:
            raise ValueError(f"method {self.name!r}: unknown constraints {sorted(unknown)}")
        if (self.kind == "baseline") != (self.entry is not None):
            raise ValueError(f"method {self.name!r}: a baseline, and only a baseline, names its entry function")

    @property
    def registers_with_gpja(self) -> bool:
        """GPJA or an ablation variant: made by ``gpja register`` from the template."""
        return self.kind in ("gpja", "ablation")

    @property
    def follows_start(self) -> bool:
        """Starts where GPJA starts (``registration.start``); the paper's schedule always from the template."""
        return self.registers_with_gpja and self.schedule != "paper"

    @property
    def ablation_label(self) -> str | tuple[str, str]:
        """Row label of Table 3: ``GPJA``, ``w/o mask`` or (text, LaTeX) ``w/o L_normal``."""
        if self.kind != "ablation":
            return self.label
        if not self.without:
            return self.label
        if self.without == ("mask",):
            return "w/o mask"
        text = " ".join(f"w/o L_{c}" if c != "mask" else "w/o mask" for c in self.without)
        latex = " ".join(rf"w/o $\mathcal{{L}}_{{{c}}}$" if c != "mask" else "w/o mask" for c in self.without)
        return (text, latex)

    def schedule_settings(self, registration: dict) -> dict:
        """The settings of ``gpja register`` for this method: its section of the ``registration`` config with
        :attr:`overrides` applied."""
        return {**registration[self.schedule], **dict(self.overrides)}

    def run_function(self) -> Callable:
        """The baseline's ``run_baseline`` function (imported on demand)."""
        if self.entry is None:
            raise ValueError(f"method {self.name!r} is not a baseline")
        module, _, function = self.entry.partition(":")
        return getattr(importlib.import_module(module), function)


def _ablation(constraint: str) -> Method:
    return Method(f"gpja-no_{constraint}", f"GPJA w/o {constraint}", "ablation", without=(constraint,))


#: Every method the workflow knows by name, in table order. Imported methods are not listed: their names
#: come from the config (:func:`method` makes their entries).
METHODS: dict[str, Method] = {m.name: m for m in [
    Method("gpja", "GPJA", "gpja"),
    *(_ablation(c) for c in CONSTRAINTS),
    # GPJA before the flow stage (the unmasked-colour warm-up instead): what the flow stage buys
    Method("gpja-no_flow", "GPJA w/o flow (warm-up)", "ablation", schedule="no_flow"),
    # GPJA without the tangential hold (and its scan gate): what the hold buys
    Method("gpja-no_hold", "GPJA w/o hold", "ablation", overrides=(("hold_tangential", 0.0),)),
    # GPJA without the last stage that smooths the registration's folds out along its surface: what it buys
    Method("gpja-no_untangle", "GPJA w/o untangling", "ablation", overrides=(("untangle_iterations", 0),)),
    # GPJA without the last step along the normals onto the scan: what it buys
    Method("gpja-no_snap", "GPJA w/o snap", "ablation", overrides=(("snap_mm", 0.0),)),
    # GPJA under the template's lighting as it is, with no colour gain measured per expression: what the gain buys
    Method("gpja-no_gain", "GPJA w/o colour gain", "ablation", overrides=(("color_gain", False),)),
    # GPJA with the colour compared wherever the template renders, beyond the scan too: what the limit buys
    Method("gpja-no_scan_color", "GPJA w/ colour beyond the scan", "ablation", overrides=(("color_scan_px", None),)),
    # GPJA with the lips' material left where the first flow stage put it, not spread between the mouth's corners
    Method("gpja-no_spread", "GPJA w/o lip spread", "ablation", overrides=(("lip_spread", False),)),
    # the paper's method as published (no warm-up, one Adam, from the template): what each departure buys
    Method("gpja-paper", "GPJA (paper schedule)", "ablation", schedule="paper"),
    Method("nicp", "NICP", "baseline", entry="gpja.baselines.nicp:run_baseline"),
    Method("oracle", "Oracle (ground truth)", "reference"),
]}


def method(name: str) -> Method:
    """The registry entry of ``name``; an unregistered name is an imported method labelled by its name."""
    return METHODS.get(name) or Method(name, name, "imported")


def names(kind: str) -> list[str]:
    """The registered methods of one kind, in registry order."""
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r} is not one of {KINDS}")
    return [m.name for m in METHODS.values() if m.kind == kind]


def label(name: str) -> str:
    """Display name of a method (``gpja`` -> ``GPJA``); imported methods keep their config name."""
    return method(name).label


def check_config(config: Mapping) -> None:
    """Check the method names of a workflow config against the registry, before any job runs.

    ``registration.ablations.variants`` must be registered ablation variants, each with its schedule's
    section (``registration.paper`` for ``gpja-paper``); every key of ``baselines``
    but ``external`` a registered baseline; an imported method (``baselines.external``) may not take a
    registered method's name, nor another imported method's.

    Raises:
        InputError: naming the config key and the known names.
    """
    registration = config.get("registration") or {}
    ablations = registration.get("ablations") or {}
    for name in ablations.get("variants") or []:
        if method(name).kind != "ablation":
            raise InputError("registration.ablations.variants",
                             f"unknown ablation variant {name!r}; known: {', '.join(names('ablation'))}")
        if method(name).schedule not in registration:
            raise InputError(f"registration.{method(name).schedule}",
                             f"missing: the variant {name!r} takes its schedule from it")
    baselines = config.get("baselines") or {}
    for key in baselines:
        if key != "external" and method(key).kind != "baseline":
            raise InputError(f"baselines.{key}",
                             f"not a registered baseline; known: {', '.join(names('baseline'))} (and external)")
    seen: set[str] = set()
    for entry in baselines.get("external") or []:
        name = entry["name"]
        if name in METHODS or name in seen:
            raise InputError("baselines.external", f"imported method name {name!r} is taken "
                                                   f"({'a registered method' if name in METHODS else 'twice'})")
        seen.add(name)
