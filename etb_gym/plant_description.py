"""A plant's plain description (the plant-file format, docs/plant-file.md) read into constructor arguments,
and the core components of the paper's nine models by name.

``Plant.from_dict`` and ``make_plant`` (etb_gym/plant.py) are the public doors; this module checks a
description key by key so that every error names the key (``rotor.inertia_kg_m2``,
``effects[1].params.gain``), the value and what was expected. Reading and writing the files themselves is
etb_gym/plantfile.py.
"""
from __future__ import annotations

import dataclasses
import re
from typing import Mapping

from .components.base import REGISTRY, show
from .components.drive import DRIVES, InductanceTable
from .components.friction import FRICTIONS
from .components.rotor import RotorParams
from .components.spring import LimpHomeSpring
from .components.stops import EndStops
from .components.supply import SupplyParams

MODELS = tuple(f"{f}{d}" for f in "123" for d in "ABC")
CORE_ROLES = ("drive", "friction", "spring", "stops")
PLANT_SCHEMA = "etb-gym/plant/1"
TOP_KEYS = ("schema", "model", "control_period_s", "substeps", "rotor", "supply", "effects", *CORE_ROLES)


def model_components(model: str) -> dict:
    """The core components of one of the paper's models ("1A".."3C"), with the documented defaults."""
    m = re.fullmatch(r"([123])([ABC])", str(model).strip().upper())
    if not m:
        raise ValueError(f"unknown model {model!r}: expected one of {', '.join(MODELS)} "
                         "(friction 1 viscous / 2 Dahl / 3 LuGre, drive A linear / B nonlinear L / C flux)")
    f, d = m.group(1), m.group(2)
    return {"drive": DRIVES[d](), "friction": FRICTIONS[f](), "spring": LimpHomeSpring(), "stops": EndStops(),
            "model": f + d}


def kind_of(v) -> str:
    """What a value read from a file is, in the file's words."""
    return {bool: "true/false", str: "text", dict: "a table", list: "a list"}.get(type(v), type(v).__name__)


def table(v, where) -> Mapping:
    if not isinstance(v, Mapping):
        raise ValueError(f"{where}: expected a table, got {kind_of(v)}")
    return v


def _inductance_table(v, where) -> InductanceTable:
    t = dict(table(v, where))
    tn = [f.name for f in dataclasses.fields(InductanceTable)]
    bad = sorted(set(t) - set(tn))
    if bad or set(tn) - set(t):
        raise ValueError(f"{where}: expected exactly the keys {tn}, got {sorted(t)}")
    try:
        return InductanceTable(**t)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {e}") from None


def params_of(P, values, where):
    """An instance of the parameter class ``P`` from a table of its fields."""
    values = dict(table(values, where))
    names = [f.name for f in dataclasses.fields(P)]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ValueError(f"{where} has unknown key(s) {unknown}; valid: {names}")
    if "inductance_table" in values and values["inductance_table"] is not None:
        values["inductance_table"] = _inductance_table(values["inductance_table"], f"{where}.inductance_table")
    try:
        return P(**values)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {e}") from None


def component(spec, where):
    """A component from a table ``{kind, params, name}`` (None stays None)."""
    if spec is None:
        return None
    if not isinstance(spec, Mapping) or "kind" not in spec:
        raise ValueError(f"{where}: expected a table with a 'kind' key (one of {sorted(REGISTRY)})")
    extra = sorted(set(spec) - {"kind", "params", "name"})
    if extra:
        raise ValueError(f"{where} has unknown key(s) {extra}; valid: ['kind', 'name', 'params']")
    kind = spec["kind"]
    if not isinstance(kind, str) or kind not in REGISTRY:
        raise ValueError(f"{where}.kind = {show(kind)} is unknown; valid: {sorted(REGISTRY)}")
    C = REGISTRY[kind]
    obj = C(params_of(C.Params, spec.get("params", {}), f"{where}.params"))
    if spec.get("name") is not None:
        if not isinstance(spec["name"], str) or not spec["name"].strip():
            raise ValueError(f"{where}.name = {show(spec['name'])}: expected a non-empty text")
        obj.name = spec["name"]
    return obj


def _check_top(d: Mapping) -> None:
    table(d, "the plant description")
    unknown = sorted(set(d) - set(TOP_KEYS))
    if unknown:
        raise ValueError(f"unknown key(s) {unknown}; valid: {sorted(TOP_KEYS)}")
    if "schema" in d and d["schema"] != PLANT_SCHEMA:
        raise ValueError(f"schema = {show(d['schema'])} is not supported: expected {PLANT_SCHEMA!r} "
                         f"(written by this version of etb-gym)")
    if d.get("model") is not None and not isinstance(d["model"], str):
        raise ValueError(f"model = {show(d['model'])}: expected one of {', '.join(MODELS)} as text")
    for key, kind in (("control_period_s", "a number of seconds > 0"), ("substeps", "a whole number >= 1")):
        v = d.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or (key == "substeps" and not isinstance(v, int))):
            raise ValueError(f"{key} = {show(v)}: expected {kind}, got {kind_of(v)}")


def _effects(d: Mapping) -> list:
    effects = d.get("effects", [])
    if not isinstance(effects, (list, tuple)):
        raise ValueError(f"effects: expected a list of tables ([[effects]] in TOML), got {kind_of(effects)}")
    effects = [component(e, f"effects[{k}]") for k, e in enumerate(effects)]
    names = [e.name for e in effects if "name" in e.__dict__]
    clash = sorted({n for n in names if names.count(n) > 1 or n in CORE_ROLES})
    if clash:
        raise ValueError(f"effects: the name(s) {clash} are used twice or by a core component: expected "
                         f"distinct names other than {', '.join(CORE_ROLES)}")
    return effects


def plant_arguments(d: Mapping) -> dict:
    """The ``Plant(...)`` keyword arguments a description gives: its model's core components, replaced by the
    ones it lists, and its rotor, supply, effects, control period and substeps."""
    _check_top(d)
    base = model_components(d["model"]) if d.get("model") else None
    kw = {}
    for role in CORE_ROLES:
        if role in d:
            kw[role] = component(d[role], role)
        elif base is not None:
            kw[role] = base[role]
    if kw.get("drive") is None:
        raise ValueError(f"expected a 'model' ({', '.join(MODELS)}) or a 'drive' table")
    kw["rotor"] = params_of(RotorParams, d["rotor"], "rotor") if "rotor" in d else RotorParams()
    kw["supply"] = params_of(SupplyParams, d["supply"], "supply") if "supply" in d else SupplyParams()
    kw["effects"] = _effects(d)
    return dict(kw, control_period_s=d.get("control_period_s", 1e-3), substeps=d.get("substeps", 20),
                model=d.get("model"))
