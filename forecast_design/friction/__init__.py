"""Friction models as composable terms and their identification from logs.

Names are loaded on first use (PEP 562): ``forecast_design.friction.laws`` or
``MODEL_NAMES`` do not pull in the identification machinery (casadi, scipy.signal).
The function :func:`identify` shares its name with the submodule that defines it; the
package attribute is always the function (import the module with
``from forecast_design.friction.identify import ...``).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any

_HOME = {
    "Adequacy": "adequacy",
    "AsymmetricCoulomb": "terms",
    "AsymmetricViscous": "terms",
    "AxisLog": "logs",
    "Coulomb": "terms",
    "FilterSettings": "derivatives",
    "FrictionFit": "results",
    "FrictionModel": "terms",
    "FrictionValidation": "results",
    "Harmonics": "terms",
    "IdentificationData": "results",
    "IllConditionedWarning": "results",
    "Inertia": "terms",
    "Kinematics": "derivatives",
    "LuGre": "terms",
    "MODEL_NAMES": "terms",
    "Offset": "terms",
    "PositionFriction": "terms",
    "SampleSelection": "selection",
    "SelectionResult": "selection",
    "Stribeck": "terms",
    "Term": "terms",
    "Viscous": "terms",
    "decimate_columns": "derivatives",
    "identify": "identify",
    "log_arrays": "compat",
    "default_filter_settings": "derivatives",
    "differentiate": "derivatives",
    "experiment_scales": "source",
    "FrictionLog": "source",
    "friction_log": "source",
    "fit_data": "identify",
    "fit_friction": "identify",
    "fit_friction_experiment": "compat",
    "fit_percent": "results",
    "friction_model": "terms",
    "load_axis_csv": "logs",
    "lugre_force": "terms",
    "predict_data": "identify",
    "prepare_identification_data": "identify",
    "stribeck_force": "terms",
    "validate": "identify",
    "validate_experiment": "compat",
    "zoh_align": "source",
}

__all__ = sorted(_HOME)


def __getattr__(name: str) -> Any:
    if name in _HOME:
        value = getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOME))


class _Package(types.ModuleType):
    """Keeps a public function from being shadowed by the submodule of the same name."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _HOME and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
