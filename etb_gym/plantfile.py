"""Plant files: a plant (parameters and extra components) as TOML or JSON. Format: docs/plant-file.md.

    save_plant(plant, "calibrated_plant.toml")      # written atomically
    plant = load_plant("calibrated_plant.toml")     # or .json; gym.make("ETB-3B-v0", plant=path)
    sensor = load_sensor("calibrated_plant.toml")   # its [sensor] section (a twin's reading model), or None
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from .io import write_atomic
from .plant import Plant


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int,)):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"cannot write non-finite value {v!r} to a plant file")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _toml_table(lines, prefix, d, array=False):
    scalars = {k: v for k, v in d.items() if not isinstance(v, dict) and v is not None}
    tables = {k: v for k, v in d.items() if isinstance(v, dict)}
    lines.append(f"[[{prefix}]]" if array else f"[{prefix}]")
    for k, v in scalars.items():
        lines.append(f"{k} = {_toml_value(v)}")
    for k, v in tables.items():
        _toml_table(lines, f"{prefix}.{k}", v)


def dumps_toml(d: dict) -> str:
    lines = [f"# etb-gym plant file ({d.get('schema', 'etb-gym/plant/1')}), see docs/plant-file.md"]
    top = {k: v for k, v in d.items() if not isinstance(v, (dict, list)) and v is not None}
    for k, v in top.items():
        lines.append(f"{k} = {_toml_value(v)}")
    for k, v in d.items():
        if isinstance(v, dict):
            lines.append("")
            _toml_table(lines, k, v)
    for e in d.get("effects", []):
        lines.append("")
        _toml_table(lines, "effects", e, array=True)
    return "\n".join(lines) + "\n"


def save_plant(plant: Plant, path, sensor: dict | None = None) -> Path:
    """Write ``plant`` to ``path`` (.toml or .json) atomically; ``sensor``: a ``[sensor]`` section (the twin's
    reading model, components.sensor.sensor_section_dict), checked before anything is written."""
    path = Path(path)
    d = plant.to_dict()
    if sensor is not None:
        from .components.sensor import sensor_section
        sensor_section(sensor)
        d["sensor"] = sensor
    if path.suffix == ".json":
        text = json.dumps(d, indent=2)
    elif path.suffix == ".toml":
        text = dumps_toml(d)
    else:
        raise ValueError(f"plant file {path}: expected a .toml or .json file name")
    return write_atomic(path, text)


def load_plant(path) -> Plant:
    """Read a plant file (.toml or .json). Errors name the file and the offending key; the file is only read.
    A ``[sensor]`` section is checked too (:func:`load_sensor` returns it); the plant does not hold it."""
    return load_plant_and_sensor(path)[0]


def load_plant_and_sensor(path) -> tuple[Plant, dict | None]:
    """A plant file read once: the plant and its ``[sensor]`` section checked
    (components.sensor.sensor_section's dict), or None where the file has none (the env reads both)."""
    from .components.sensor import sensor_section
    d = _read(path)
    try:
        plant = Plant.from_dict({k: v for k, v in d.items() if k != "sensor"})
    except (ValueError, TypeError, KeyError) as e:
        raise ValueError(f"plant file {path}: {e}") from None
    return plant, None if d.get("sensor") is None else sensor_section(d["sensor"])


def load_sensor(path) -> dict | None:
    """A plant file's ``[sensor]`` section, checked (components.sensor.sensor_section: offset_rad, gain, delay_s,
    curve, filter), or None where the file has none."""
    d = _read(path)
    return None if d.get("sensor") is None else d["sensor"]


def _read(path) -> dict:
    """The parsed plant file, its [sensor] section checked."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"plant file {path} does not exist")
    if not path.is_file():
        raise ValueError(f"plant file {path}: is not a file")
    if path.suffix.lower() not in (".toml", ".json"):
        raise ValueError(f"plant file {path}: expected a .toml or .json file")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise ValueError(f"plant file {path}: byte {e.start} is not UTF-8 text: expected a TOML or JSON text file "
                         f"(save it as UTF-8)") from None
    try:
        if path.suffix.lower() == ".json":
            d = json.loads(text, parse_constant=_no_constant)
        else:
            import tomllib

            d = tomllib.loads(text)
    except ValueError as e:
        fmt = path.suffix.lower()[1:].upper()
        raise ValueError(f"plant file {path}: cannot parse as {fmt} ({e}): expected a {fmt} file as described in "
                         f"docs/plant-file.md") from None
    if not isinstance(d, dict):
        raise ValueError(f"plant file {path}: expected a table (an object) at the top level")
    if d.get("sensor") is not None:
        from .components.sensor import sensor_section
        try:
            sensor_section(d["sensor"])
        except ValueError as e:
            raise ValueError(f"plant file {path}: {e}") from None
    return d


def _no_constant(name):
    raise ValueError(f"{name} is not a number a plant file may hold (expected finite numbers)")
