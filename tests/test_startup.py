"""Start-up: building the command line imports nothing heavy (issue 16)."""

from __future__ import annotations

import re
import subprocess
import sys

HEAVY = ("scipy", "casadi", "sympy", "matplotlib", "numba", "pandas", "pyarrow", "dask", "distributed",
         "control", "cvxpy", "serial")


def _imported(code: str) -> set[str]:
    proc = subprocess.run([sys.executable, "-X", "importtime", "-c", code], capture_output=True, text=True,
                          check=True, timeout=120)
    return {m.group(1).split(".")[0] for m in re.finditer(r"^import time:\s+\d+ \|\s+\d+ \| *(\S+)$",
                                                             proc.stderr, re.M)}


def test_building_the_parser_imports_no_heavy_library():
    modules = _imported("from forecast_design.cli import build_parser; build_parser()")
    assert "forecast_design" in modules and "numpy" in modules  # the probe sees imports at all
    assert not modules & set(HEAVY), sorted(modules & set(HEAVY))


def test_loading_an_experiment_imports_only_the_columnar_reader(tmp_path):
    code = ("import numpy as np; from forecast_design import Design, experiment_from_arrays, save_experiment, "
            "load_experiment; t = np.arange(5) / 1e3; "
            f"save_experiment(experiment_from_arrays(Design.nominal('soft'), 1e3, t, t, t, t), r'{tmp_path / 'r.toml'}'); "
            f"load_experiment(r'{tmp_path / 'r.toml'}')")
    modules = _imported(code)
    assert "pyarrow" in modules
    assert not modules & (set(HEAVY) - {"pyarrow"}), sorted(modules & set(HEAVY))
