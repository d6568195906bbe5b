"""The benchmark runner simulates a cell's repetitions as one batch, bit-equal to one `simulate` per run (issue 16)."""

import dataclasses
import json

import numpy as np

from forecast_design.benchmark import BenchmarkSpec, parse_compensators, parse_reference, run_cell
from forecast_design.effects import Stiction
from forecast_design.environments import environment_preset
from forecast_design.executor import LocalExecutor
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design
from forecast_design.simulation import simulate
from forecast_design.simulation.scenario import Variability

SFM = {"viscous": 0.3, "coulomb": 0.4, "sin1": 0.01}


def _tasks():
    spec = BenchmarkSpec(controllers=(PD(P=5.0, D=0.1),), compensators=parse_compensators("sfm,ea-fob"),
                         environments=(("exp-soft", environment_preset("exp-soft")),),
                         references=(parse_reference("step:0.2:0.3"),), repetitions=3,
                         effects=(Stiction(F_s_a=(0.05,), F_s_b=(0.02,)),), sfm_deadband=0.01)
    return [(spec.cell_key(c, SFM), c, spec, SFM) for c in spec.cells()]


def _single_run_cell(task):
    """tau_s of every repetition and the expected response as the runner computed them one `simulate` at a time."""
    _, cell, spec, sfm_params = task
    design = Design(testbed=Design.nominal().testbed, environment=cell.environment, controller=cell.controller,
                    compensator=cell.compensator)
    var = Variability(repetitions=spec.repetitions, viscous_drift=spec.viscous_drift, seed=spec.seed)
    common = dict(reference=cell.reference, duration_s=cell.duration_s, rate_hz=spec.rate_hz)
    expected = simulate(dataclasses.replace(design, compensator=Compensator(kind="none")), **common,
                        include_nominal_viscous=False, process_noise_std=0.0, encoder_counts=None)
    sfm = cell.compensator.kind == "sfm"
    runs = [simulate(design, **common, effects=var.effects_of(spec.effects, i), initial_angle=float(a),
                     seed=spec.seed + 1 + i, sfm_params=sfm_params if sfm else None,
                     sfm_deadband=spec.sfm_deadband if sfm else 0.0)
            for i, a in enumerate(var.initial_angles())]
    return np.array([r.tau_s for r in runs]), expected.tau_s


def test_cells_equal_the_single_run_path_bit_for_bit_in_process_and_in_workers():
    tasks = _tasks()
    here = [run_cell(t) for t in tasks]                       # main process: the batch on numba's pool
    with LocalExecutor(2) as ex:                              # worker processes: one thread per batch
        there = ex.map(run_cell, tasks)
    for task, a, b in zip(tasks, here, there):
        tau, expected = _single_run_cell(task)
        # the cell holds every sample of every run (the indicators recompute from its traces)
        assert a.trace_step == 1 and np.array_equal(a.tau_s, tau) and np.array_equal(b.tau_s, tau)
        assert np.array_equal(a.expected, expected)
        for i, row in enumerate(a.runs):
            assert row["mae_N_m"] == float(np.mean(np.abs(tau[i] - expected)))
        assert json.dumps(a.to_mapping(), sort_keys=True) == json.dumps(b.to_mapping(), sort_keys=True)  # NaN-safe
    # the SFM cell's repetitions differ (angle-dependent stiction): the batch kept them apart
    assert not np.array_equal(here[0].tau_s[0], here[0].tau_s[1])
