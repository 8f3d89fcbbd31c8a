"""The vehicle models odocal knows, by name, as :mod:`odocal.io.registry` is for readers.

Pure Python: the settings check ``[vehicle] model`` against :func:`names` and size their
per-parameter tuples by :func:`layout` without loading numpy; :func:`model` loads the model
itself. A model is registered with its layout and its wheel inputs (the drive's columns).
"""

from __future__ import annotations

import difflib
import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

from odocal.errors import ConfigError, DataError
from odocal.model.layout import FOUR_WHEEL, REAR_AXLE, Layout

if TYPE_CHECKING:
    from odocal.model.four_wheel import FourWheelModel
    from odocal.model.protocol import VehicleModel

#: The model a setting, a calibration.json or a fleet store that names none means (all of
#: odocal's results before models were named are the rear axle's).
DEFAULT = "rear_axle"


@dataclass(frozen=True)
class Entry:
    """A registered model: its name, what it is in words, its layout, its wheel inputs, and
    where its model object lives (``module:attribute``, imported on first use)."""

    name: str
    summary: str
    layout: Layout
    wheel_inputs: tuple[str, ...]
    where: str


_ENTRIES: dict[str, Entry] = {e.name: e for e in (
    Entry("rear_axle", "two rear wheel rates (METHOD 1: c_e, c_d, t_r, d)", REAR_AXLE,
          ("n_rl", "n_rr"), "odocal.model.vehicle:MODEL"),
    Entry("four_wheel", "four wheel rates and the steering-wheel angle (the rear axle's four, "
          "then c_f, c_fd, t_f, L, ratio, s_0)", FOUR_WHEEL, ("n_fl", "n_fr", "n_rl", "n_rr"),
          "odocal.model.four_wheel:FOUR_WHEEL_MODEL"),
)}


def names() -> tuple[str, ...]:
    """The registered models' names."""
    return tuple(_ENTRIES)


def entry(name: str) -> Entry:
    """The registered model ``name``, or a one-line ConfigError naming the known ones."""
    try:
        return _ENTRIES[name]
    except (KeyError, TypeError):
        close = difflib.get_close_matches(str(name), _ENTRIES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(f"unknown vehicle model {name!r}{hint}; known: "
                          f"{', '.join(_ENTRIES)}") from None


def layout(name: str) -> Layout:
    """The parameter layout of model ``name``."""
    return entry(name).layout


def model(name: str = DEFAULT) -> VehicleModel | FourWheelModel:
    """The model object ``name`` (its equations: loads numpy)."""
    module, attribute = entry(name).where.split(":")
    found: VehicleModel | FourWheelModel = getattr(importlib.import_module(module), attribute)
    return found


def check_stated(stated: object, expected: str, what: str) -> str:
    """The model a file states (``stated``: its ``"model"`` value, None where it names none:
    the rear axle), if it is ``expected``; else a one-line DataError naming ``what``."""
    name = DEFAULT if stated is None else stated
    if not isinstance(name, str) or name not in _ENTRIES:
        raise DataError(f"{what} names the vehicle model {stated!r}, which this odocal does "
                        f"not know (known: {', '.join(_ENTRIES)})")
    if name != expected:
        raise DataError(f"{what} is a calibration of the {name} model, not of the {expected} "
                        "model this run uses ([vehicle] model)")
    return name


def require_rear_axle(name: str, what: str) -> None:
    """A one-line ConfigError where ``what`` (a command, a part of odocal) is asked to run a
    model other than the rear axle: in this version ``odocal calibrate`` (and
    :func:`odocal.calibrate`), ``odocal validate`` and ``odocal fleet calibrate`` take the
    others."""
    if name != DEFAULT:
        raise ConfigError(f"{what} takes the {DEFAULT} model only in this version; the {name} "
                          "model ([vehicle] model) is calibrated by 'odocal calibrate' and "
                          "'odocal fleet calibrate'")
