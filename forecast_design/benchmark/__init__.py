"""Benchmark force controllers across a set of environments on the virtual testbed (paper Sections 2 and 7).

``forecast-design benchmark`` in library form::

    from forecast_design.benchmark import BenchmarkSpec, run_benchmark, result_table
    spec = BenchmarkSpec(controllers=(PD(P=5, D=0.1), parse_controller("pid:6:20:0.05:0.002")),
                         compensators=parse_compensators("none,ea-fob"),
                         environments=tuple(resolve_environments("soft,stiff")),
                         references=(parse_reference("step:0.2"),), repetitions=10)
    cells, info = run_benchmark(spec, out="bench", executor=make_executor())
    df = result_table(cells)

Modules: :mod:`.spec` (what runs), :mod:`.metrics` (indicators), :mod:`.runner` (cells
through :mod:`forecast_design.executor`, cached by their inputs), :mod:`.aggregate`
(mean/best/worst per environment and over the set, Parquet + CSV + JSON),
:mod:`.report` (Markdown), :mod:`.recorded` (recorded runs from a folder of experiments,
grouped into cells by their TOML). Plots: :mod:`forecast_design.plotting.benchmark`.
"""

from .aggregate import COLUMNS, read_results, result_rows, result_table, summary, write_summary, write_tables
from .metrics import INDICATOR_DEFINITIONS, METRICS, repeatability_per_run, step_metrics, tracking_bandwidth_hz
from .recorded import find_runs, group_runs, run_recorded
from .report import markdown_report, write_report
from .runner import CellResult, run_benchmark, run_cell, write_traces
from .spec import BenchmarkSpec, Cell, parse_compensators, parse_controller, parse_reference

__all__ = [
    "BenchmarkSpec", "Cell", "CellResult", "parse_controller", "parse_compensators", "parse_reference",
    "run_benchmark", "run_cell", "result_rows", "result_table", "write_tables", "summary", "write_summary",
    "read_results",
    "markdown_report", "write_report", "step_metrics", "tracking_bandwidth_hz", "repeatability_per_run",
    "METRICS", "COLUMNS", "run_recorded", "find_runs", "group_runs", "write_traces", "INDICATOR_DEFINITIONS",
]
