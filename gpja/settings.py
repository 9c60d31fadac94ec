"""Settings dataclasses that read themselves from a config section, and the config's cross-field check.

Every stage's settings are a frozen dataclass whose defaults are written once, in the dataclass,
and whose cross-field rules (one lambda per level, ...) are checked in its ``__post_init__``. Each
reads its config section through :func:`from_section`, bound as ``from_config``::

    @dataclass(frozen=True)
    class Schedule:
        lambdas: tuple[float, ...] = (200.0, 120.0, 80.0, 50.0)
        ...
        from_config = classmethod(from_section)

    Schedule.from_config(config["registration"]["gpja"], "registration.gpja")

:func:`from_section` rejects unknown keys, turns lists into tuples, coerces numbers to the
field's type and leaves absent keys at the dataclass default. Field metadata adapts a field
to the config layout:

* ``{CONFIG_KEY: "faces"}``: the field is read from another key than its name;
* a field whose type is itself a settings dataclass is read from the same (flat) section,
  from that dataclass's keys; ``{HIDDEN: ("color_pool", ...)}`` on it lists the nested keys
  the section does not offer (they keep the field default's values).

:func:`check_config` builds every settings object of a workflow config, so that a bad
combination stops ``snakemake`` at load time with one line naming the config key.
"""
from __future__ import annotations

import dataclasses
import importlib
import types
import typing
from typing import Any, Mapping

from gpja.errors import InputError

#: Field metadata: the config key of a field when it differs from the field's name.
CONFIG_KEY = "config_key"
#: Field metadata of a nested settings field: the nested keys its section does not offer.
HIDDEN = "hidden"

#: The settings sections of a workflow config: dotted config key -> "module:Class".
SECTIONS = {
    "synthetic": "gpja.data.synthetic.writer:SynthConfig",
    "registration.template": "gpja.register.template:TemplateSettings",
    "registration.gpja": "gpja.register.multiscale:Schedule",
    "registration.paper": "gpja.register.multiscale:Schedule",  # the gpja-paper variant's schedule
    "baselines.nicp.settings": "gpja.baselines.nicp:NicpSettings",
    "metrics": "gpja.metrics.evaluate:MetricSettings",
    "figures": "gpja.report.figures:FigureSettings",
    "applications.remesh": "gpja.apply.settings:RemeshSettings",
    "applications.animation": "gpja.apply.settings:AnimationSettings",
    "applications.export": "gpja.apply.settings:ExportSettings",
    "applications.reparam": "gpja.apply.settings:ReparamSettings",
}
#: Keys of a section that the workflow itself reads: they are no settings field.
WORKFLOW_KEYS = {"synthetic": ("enabled", "raw_root")}
#: Settings fields the workflow fills from elsewhere in the config (not keys of their section):
#: ``SynthConfig.expressions`` is the run's expressions plus the template's.
DERIVED_KEYS = {"synthetic": ("expressions",)}


def is_settings(tp: Any) -> bool:
    """Whether ``tp`` is a dataclass type (read from a config section by :func:`from_section`)."""
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def config_key(f: dataclasses.Field) -> str:
    """The config key of a settings field (its name unless its metadata says otherwise)."""
    return f.metadata.get(CONFIG_KEY, f.name)


def section_keys(cls: type) -> tuple[str, ...]:
    """Every key a config section of settings class ``cls`` accepts, in field order (nested settings flattened).

    Raises:
        TypeError: two fields (one of them nested) claim the same key (a programming error).
    """
    hints = typing.get_type_hints(cls)
    keys: list[str] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if is_settings(hints[f.name]):
            hidden = set(f.metadata.get(HIDDEN, ()))
            keys += [k for k in section_keys(hints[f.name]) if k not in hidden]
        else:
            keys.append(config_key(f))
    if len(set(keys)) != len(keys):
        raise TypeError(f"{cls.__name__}: two settings fields share a config key in {keys}")
    return tuple(keys)


def from_section(cls: type, section: Mapping[str, Any] | None = None, source: str = "config"):
    """Build settings class ``cls`` from a config section; absent keys keep the dataclass defaults.

    Args:
        cls: a dataclass; every ``init`` field is read from the section (see the module docstring).
        section: the config mapping (parsed YAML or JSON); None = every default.
        source: the file, option or dotted config key the section came from, named in errors.
    Returns:
        ``cls(...)`` with every given key converted to its field's type: lists to tuples, numbers
        to the field's ``int``/``float``, nested settings (and tuples of them, e.g. NICP steps
        given as lists or mappings) built in turn.
    Raises:
        InputError(source, ...): the section is no mapping, has an unknown key, a value of the
        wrong type, or breaks a cross-field rule of the dataclass's ``__post_init__``.
    """
    if section is None:
        section = {}
    if not isinstance(section, Mapping):
        raise InputError(source, f"expected a mapping of {cls.__name__} settings, got {type(section).__name__}")
    known = section_keys(cls)
    unknown = sorted(set(section) - set(known))
    if unknown:
        raise InputError(source, f"unknown key(s) {', '.join(map(str, unknown))}; known: {', '.join(known)}")
    try:
        return _build(cls, dict(section), None)
    except InputError:
        raise
    except (TypeError, ValueError) as err:
        raise InputError(source, str(err)) from None


def _build(cls: type, section: dict, base: Any):
    """``cls`` from a section whose keys were checked; fields absent from it come from ``base`` (or the defaults)."""
    hints = typing.get_type_hints(cls)
    given = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        tp = hints[f.name]
        if is_settings(tp):
            hidden = set(f.metadata.get(HIDDEN, ()))
            nested = {k: section[k] for k in section_keys(tp) if k in section and k not in hidden}
            if nested:
                given[f.name] = _build(tp, nested, _field_default(f))
        elif config_key(f) in section:
            given[f.name] = coerce(section[config_key(f)], tp, config_key(f))
    return cls(**given) if base is None else dataclasses.replace(base, **given)


def _field_default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def coerce(value: Any, tp: Any, where: str) -> Any:
    """``value`` (parsed YAML/JSON) as type ``tp``: bool, int, float, str, Optional, ``tuple[X, ...]``, a dataclass.

    Integral floats become ints (``3.0`` -> 3), ints become floats; booleans are never numbers.
    A dataclass is built from a mapping of its fields or a list of them in field order.

    Raises:
        ValueError: naming ``where`` (the key, with ``[i]`` for tuple items), when the value does not fit.
    """
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:
            return coerce(value, options[0], where)
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or (isinstance(value, float) and not value.is_integer()):
            raise ValueError(f"{where}: expected an integer, got {value!r}")
        return int(value)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"{where}: expected a string, got {value!r}")
        return value
    if origin is tuple:
        if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (list, tuple)):
            raise ValueError(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise ValueError(f"{where}: expected {len(args)} entries, got {len(value)}")
        return tuple(coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if is_settings(tp):
        return _item(value, tp, where)
    return value


def _item(value: Any, cls: type, where: str):
    """A dataclass from a mapping of its fields, or a list of them in field order (a tuple item, e.g. a NICP step)."""
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    if isinstance(value, (list, tuple)):
        if len(value) != len(names):
            raise ValueError(f"{where}: expected [{', '.join(names)}], got {list(value)!r}")
        value = dict(zip(names, value))
    if not isinstance(value, Mapping):
        raise ValueError(f"{where}: expected [{', '.join(names)}] or a mapping of them, got {value!r}")
    unknown = sorted(set(value) - set(section_keys(cls)))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(map(str, unknown))}; known: {', '.join(names)}")
    try:
        return _build(cls, dict(value), None)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where}: {err}") from None


def settings_class(key: str) -> type:
    """The settings dataclass of a config section (a key of :data:`SECTIONS`), imported on demand."""
    module, name = SECTIONS[key].split(":")
    return getattr(importlib.import_module(module), name)


def lookup(config: Mapping[str, Any], key: str) -> Any:
    """The value at dotted ``key`` of ``config`` (None where a level is missing)."""
    node: Any = config
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return node


def data_expressions(config: Mapping[str, Any]) -> list[str]:
    """The expressions a run reads: the config's, then the template's when it is not among them."""
    expressions = list(config["expressions"])
    template = config["registration"]["template_expression"]
    return expressions + ([template] if template not in expressions else [])


def settings_section(config: Mapping[str, Any], key: str) -> dict | None:
    """The settings mapping of section ``key`` that a step receives: the config section without the keys
    the workflow reads itself (:data:`WORKFLOW_KEYS`), plus the fields it derives (:data:`DERIVED_KEYS`).
    None when the run does not use the section (synthesis off, NICP off, applications off, section absent)."""
    if key == "synthetic" and not (lookup(config, "synthetic.enabled")):
        return None
    if key.startswith("applications.") and not lookup(config, "applications.enabled"):
        return None
    if key == "baselines.nicp.settings" and not lookup(config, "baselines.nicp.enabled"):
        return None
    section = lookup(config, key)
    if section is None:
        return None
    section = {k: v for k, v in dict(section).items() if k not in WORKFLOW_KEYS.get(key, ())}
    if key == "synthetic":
        section["expressions"] = data_expressions(config)
    return section


def check_config(config: Mapping[str, Any]) -> dict[str, Any]:
    """Build every settings object a workflow config describes, before any job runs.

    Args:
        config: the parsed (and schema-validated) workflow config.
    Returns:
        dotted config key -> settings object, for the sections the run uses.
    Raises:
        InputError: one line, ``<config key>: <problem>``, for the first section that is wrong
        (e.g. ``registration.gpja: lambdas (3) and iterations (2) need one entry per level``).
    """
    import gpja.methods

    gpja.methods.check_config(config)  # method names against the registry
    built = {}
    for key in SECTIONS:
        section = settings_section(config, key)
        if section is not None:
            built[key] = settings_class(key).from_config(section, key)
    check_applications(config, built)
    return built


def check_applications(config: Mapping[str, Any], built: Mapping[str, Any]) -> None:
    """The applications' expressions (animation sequence, export base) must be among the run's, when they run."""
    if not lookup(config, "applications.enabled"):
        return
    available = data_expressions(config)
    for key, names in (("applications.animation", lambda s: s.sequence), ("applications.export", lambda s: [s.base])):
        wanted = names(built[key] if key in built else settings_class(key)())
        missing = [e for e in dict.fromkeys(wanted) if e not in available]
        if missing:
            raise InputError(key, f"expression(s) {', '.join(missing)} are not in the run (expressions and the "
                                  f"template's: {', '.join(available)})")
