"""JSON files (calibration.json and the other result files): written atomically, read back
with checks."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from odocal.errors import DataError, input_file, shown
from odocal.io.atomic import write_text
from odocal.model import registry
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.redaction import redact_text
from odocal.settings import vehicle_problem


def _plain(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars and arrays to Python, NaN and inf to null."""
    if isinstance(obj, str):
        return redact_text(obj)        # a URL's credentials and query are never written
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        value = float(obj)
        return value if math.isfinite(value) else None
    return obj


def write_json(path: str | Path, data: dict[str, Any], *, owned: bool = False) -> Path:
    """Write ``data`` as indented JSON, atomically (``owned``: a file of the user's folder,
    :func:`odocal.io.atomic.atomic_path`)."""
    p = Path(path)
    write_text(p, json.dumps(_plain(data), indent=2, allow_nan=False) + "\n", owned=owned)
    return p


def read_json(path: str | Path) -> dict[str, Any]:
    p = input_file(path, "file")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"'{shown(p)}' is not valid JSON: {exc}") from exc
    except RecursionError as err:
        raise DataError(f"'{shown(p)}' nests objects or arrays too deeply to read") from err
    if not isinstance(data, dict):
        raise DataError(f"'{p}' must hold a JSON object")
    return data


def read_parameters(path: str | Path, model: str = registry.DEFAULT) -> Parameters:
    """theta from a calibration.json (or any JSON with a ``theta`` object of the model's
    names) of the vehicle model ``model`` (one that names another model is refused; one that
    names none is the rear axle's, as every calibration.json before models were named), in
    that model's layout."""
    data = read_json(path)
    registry.check_stated(data.get("model"), model, f"'{shown(Path(path))}'")
    layout = registry.layout(model)
    values = _named_numbers(data, "theta", layout.names, path)
    if values is None:
        raise DataError(f"'{path}' has no \"theta\" object with {', '.join(layout.names)}")
    try:
        rear = plausible(Parameters(*values[:len(PARAMETER_NAMES)]))
    except DataError as exc:
        raise DataError(f"'{path}': {exc}") from exc
    if layout.names == PARAMETER_NAMES:
        return rear
    problem = vehicle_problem(values, layout)
    if problem is not None:
        raise DataError(f"'{path}': parameters {dict(zip(layout.names, values, strict=True))} "
                        f"are not those of a wheeled vehicle: {problem}")
    return Parameters(*values, layout=layout)


def read_uncertainty(path: str | Path, model: str = registry.DEFAULT) -> list[float]:
    """Each parameter's standard deviation in a calibration.json of ``model`` (its ``std``),
    infinite for those it says the drives did not identify (its ``identified``), or for all
    where it states neither."""
    data = read_json(path)
    layout = registry.layout(model)
    std = _named_numbers(data, "std", layout.names, path)
    flags = data.get("identified")
    if std is None or not isinstance(flags, dict):
        return [math.inf] * layout.size
    return [s if flags.get(n) is True and s >= 0 else math.inf
            for n, s in zip(layout.names, std, strict=True)]


def _named_numbers(data: dict[str, Any], key: str, names: tuple[str, ...],
                   path: str | Path) -> list[float] | None:
    """``data[key]``'s finite numbers by ``names``, in that order; None where ``data`` has no
    such object; a DataError naming what is missing or not a number."""
    obj = data.get(key)
    if not isinstance(obj, dict):
        return None
    missing = [n for n in names if n not in obj]
    if missing:
        raise DataError(f"'{path}' {key} lacks {', '.join(missing)}")
    values = []
    for name in names:
        value = obj[name]
        if not isinstance(value, int | float) or isinstance(value, bool) \
                or not math.isfinite(value):
            raise DataError(f"'{path}' {key}.{name} = {value!r} is not a finite number")
        values.append(float(value))
    return values


def plausible(theta: Parameters) -> Parameters:
    """``theta``, if a wheeled vehicle could have it (generous limits: a tenth of the gate's
    lower and ten times its upper bounds), else a DataError."""
    c_e, c_d, t_r, d = theta.as_array().tolist()
    if not all(math.isfinite(v) for v in (c_e, c_d, t_r, d)):
        raise DataError(f"parameters {theta.as_dict()} are not finite numbers")
    problem = vehicle_problem((c_e, c_d, t_r, d))
    if problem is not None:
        raise DataError(f"parameters c_e = {c_e:.6g} m, c_d = {c_d:.6g} m, t_r = {t_r:.6g} m, "
                        f"d = {d:.6g} are not those of a wheeled vehicle: {problem}")
    return theta
