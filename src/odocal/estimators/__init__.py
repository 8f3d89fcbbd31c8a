"""The estimators: one module per ``--method``, named as users type it, and their shared parts.

``inverse`` (the default), ``raw`` and ``compensated`` each return the one typed
:class:`~odocal.estimators.estimate.Estimate`. This module only names them (light: the command
line lists them without loading numpy); the pipeline runs them by these names.

May import: :mod:`odocal.checks` (what the data allow a method to fit), :mod:`odocal.data`,
:mod:`odocal.model` and the leaves (:mod:`odocal.settings`, :mod:`odocal.errors`,
:mod:`odocal.arrays`, :mod:`odocal.correlation`); nothing above.
"""

from __future__ import annotations

from types import MappingProxyType

#: Every calibration method, with what it is in a few words.
METHOD_SUMMARIES: MappingProxyType[str, str] = MappingProxyType({
    "inverse": "errors-in-variables: the wheel revolutions the reference motion implies, fitted "
               "to the measured ones (wheel noise independent of the reference cannot bias "
               "it)",
    "compensated": "the paper's three-step architecture (batch G-N, input compensation, G-N)",
    "raw": "batch Gauss-Newton on all selected segments with the measured wheel rates",
})
METHOD_NAMES: tuple[str, ...] = tuple(METHOD_SUMMARIES)
#: The method a calibration uses unless told otherwise.
DEFAULT_METHOD = "inverse"
