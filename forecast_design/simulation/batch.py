"""Many runs of the virtual testbed in one call: Monte-Carlo over seeds, parameters, environments and effects.

:func:`simulate_batch` runs a list of :class:`BatchRun` (each its own design, effects, noise
seed, initial angle and optionally reference) with shared options (duration, rate, substeps,
encoders, ...). Every run is prepared exactly as :func:`~.run.simulate` prepares it (the same
validation, plant packing :func:`~.plant.build_plant`, stability check and controller program of
:mod:`forecast_design.program`) and stepped by the same compiled closed loop ``run._loop`` (which steps
the plant through :func:`~.plant.advance_period`), one run per thread of numba's pool
(``prange``): run ``i`` of a batch equals ``simulate`` with the same arguments bit for bit
(``tests/test_simulation_batch.py``).

Each thread works on private copies of its run's inputs and logs: numba reference-counts the
arrays the inlined plant step receives, and two threads counting on the same array (slices of
one batch array share its counter) would contend for one cache line on every substep.

Memory: the logs take 112 bytes per sample and run (6 measured and 8 true float64 columns),
e.g. 4.5 MB for a 20 s run at 2 kHz; split larger Monte-Carlo studies into batches.

:func:`simulate_scenario` runs every repetition of a scenario's ``[variability]`` (paper
Section 2: each repetition from its own initial angle, hence its own angle-dependent stiction
level and Stribeck velocity, with drifting viscous friction) as one batch.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Iterator, Sequence

import numpy as np

from ..discrete import njit, prange
from ..errors import ParameterError
from ..params import Design
from ..limits import check_limit
from .plant import history_length
from .run import _MEAS, _TRUTH, SimulationResult, _check_kernel_cache, _loop, _prepare, _Prepared, run_code
from .scenario import Scenario

__all__ = ["BatchRun", "BatchResult", "simulate_batch", "simulate_scenario", "scenario_runs"]

#: Options of :func:`~.run.simulate` shared by every run of a batch.
SHARED_OPTIONS = ("velocity_cutoff_hz", "sfm_deadband", "torque_limit", "encoder_counts",
                  "process_noise_std", "include_nominal_viscous", "sfm_params", "step_timeout_s",
                  "torque_sensor", "encoder_jitter_counts")


@dataclass(frozen=True, slots=True)
class BatchRun:
    """One run of a batch: what may differ from run to run.

    Attributes
    ----------
    design : Design
        Nominal testbed and environment, controller and compensator (observers are built on it).
    effects : tuple
        Unmodelled effects of this run's hardware (:mod:`forecast_design.effects`), e.g. a
        :class:`~forecast_design.effects.Stiction` with its angle harmonics.
    seed : int
        Process-noise seed.
    initial_angle : float
        Absolute motor angle at theta = 0 [rad].
    reference : Reference, callable or array, optional
        This run's force reference (closed loop) or torque profile (open loop); None: the
        batch's.
    description : str
        Free text of the run's experiment.
    """

    design: Design
    effects: tuple = ()
    seed: int = 0
    initial_angle: float = 0.0
    reference: Any = None
    description: str = ""


@dataclass(frozen=True, slots=True)
class BatchResult:
    """The logs of a batch, stacked: ``measured[i]`` and ``true[i]`` are run ``i``'s.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times [s].
    measured : ndarray, shape (runs, n, 6)
        Columns ``theta`` [rad], ``q`` [rad], ``tau_s`` [N m], ``tau_m`` [N m], ``u`` [N m],
        ``tau_frc_hat`` [N m] (:data:`MEASURED`).
    true : ndarray, shape (runs, n, 8)
        Columns ``theta`` [rad], ``omega`` [rad/s], ``q`` [rad], ``v`` [rad/s], ``z`` [rad],
        ``tau_frc`` [N m], ``tau_s`` [N m], ``tau_m_applied`` [N m] (:data:`TRUE`).
    faults : tuple
        Per run, the fault of a controller written as code that stopped (:attr:`~.run.SimulationResult.fault`)
        or None.
    """

    t: np.ndarray
    measured: np.ndarray
    true: np.ndarray
    _prepared: tuple = ()
    faults: tuple = ()

    def __len__(self) -> int:
        return self.measured.shape[0]

    def column(self, name: str) -> np.ndarray:
        """A measured column of every run, shape (runs, n): ``tau_s``, ``tau_m``, ... (:data:`MEASURED`)."""
        if name not in _MEAS:
            raise ParameterError(f"unknown measured column {name!r}; allowed: {', '.join(_MEAS)}", name="column",
                                 value=name)
        return self.measured[:, :, _MEAS.index(name)]

    def true_column(self, name: str) -> np.ndarray:
        """A true column of every run, shape (runs, n): ``tau_frc``, ``omega``, ... (:data:`TRUE`)."""
        if name not in _TRUTH:
            raise ParameterError(f"unknown true column {name!r}; allowed: {', '.join(_TRUTH)}", name="column",
                                 value=name)
        return self.true[:, :, _TRUTH.index(name)]

    def result(self, index: int) -> SimulationResult:
        """Run ``index`` as the :class:`~.run.SimulationResult` :func:`~.run.simulate` returns."""
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < len(self):
            raise ParameterError(f"run index must be in 0..{len(self) - 1}, got {index!r}", name="index",
                                 value=index)
        fault = self.faults[index] if self.faults else None
        return self._prepared[index].result(self.measured[index], self.true[index], fault)

    def results(self) -> Iterator[SimulationResult]:
        """Every run as a :class:`~.run.SimulationResult`, in order."""
        return (self.result(i) for i in range(len(self)))


#: Measured and true column names of :class:`BatchResult`.
MEASURED, TRUE = _MEAS, _TRUTH


def _pad(arrays: Sequence[np.ndarray], axis: int, dtype: Any = float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-padded stack of arrays whose length along ``axis`` varies, and those lengths."""
    sizes = np.array([a.shape[axis] for a in arrays], dtype=np.int64)
    shape = list(arrays[0].shape)
    shape[axis] = int(max(sizes.max(), 1))
    out = np.zeros((len(arrays), *shape), dtype=dtype)
    for i, a in enumerate(arrays):
        out[(i, *(slice(0, d) for d in a.shape))] = a
    return out, sizes


@njit
def _batch_run(i, n, nsub, dsub, P, HARM, nh, closed, REF, OL, torque_limit, enc_step, JIT, NOISE, KNOM, SENS, SGAIN,
               SOS, nsos, META, nmeta, GAINS, FLAGS, PAR, FFC, FFH, nffh, HL, MEAS, TRUTH):
    """Run ``i`` of the batch: ``run._loop`` on row ``i`` of every input (private copies, see the module notes)."""
    p = P[i].copy()
    harm = HARM[i, :, :nh[i]].copy()
    sos = SOS[i, :nsos[i]].copy()
    meta = META[i, :nmeta[i]].copy()
    gains = GAINS[i, :nmeta[i]].copy()
    ffh = FFH[i, :, :nffh[i]].copy()
    meas = np.empty((n, MEAS.shape[2]))
    truth = np.empty((n, TRUTH.shape[2]))
    _loop(n, nsub, dsub[i], p, harm, np.zeros(5), closed, REF[i].copy(), OL[i].copy(), torque_limit, enc_step,
          JIT[i].copy(), NOISE[i].copy(), KNOM[i], SENS[i].copy(), SGAIN, sos, np.zeros((sos.shape[0], 2)), meta, gains, FLAGS[i].copy(),
          PAR[i].copy(),
          FFC[i].copy(), ffh, np.zeros(5), meas, truth, np.zeros(HL[i]))
    # element loops, not MEAS[i] = meas: a slice assignment makes numba compile its shape-mismatch
    # message (string formatting, ~5 s of every first compile) for a shape that cannot differ here
    for r in range(n):
        for c in range(meas.shape[1]):
            MEAS[i, r, c] = meas[r, c]
        for c in range(truth.shape[1]):
            TRUTH[i, r, c] = truth[r, c]


@njit(parallel=True)
def _batch_loop(n, nsub, dsub, P, HARM, nh, closed, REF, OL, torque_limit, enc_step, JIT, NOISE, KNOM, SENS, SGAIN,
                SOS, nsos, META, nmeta, GAINS, FLAGS, PAR, FFC, FFH, nffh, HL, MEAS, TRUTH):
    """The runs on numba's thread pool, one run per thread (:func:`_batch_run`)."""
    for i in prange(P.shape[0]):
        _batch_run(i, n, nsub, dsub, P, HARM, nh, closed, REF, OL, torque_limit, enc_step, JIT, NOISE, KNOM, SENS, SGAIN,
                   SOS, nsos, META, nmeta, GAINS, FLAGS, PAR, FFC, FFH, nffh, HL, MEAS, TRUTH)


@njit
def _batch_serial(n, nsub, dsub, P, HARM, nh, closed, REF, OL, torque_limit, enc_step, JIT, NOISE, KNOM, SENS, SGAIN,
                  SOS, nsos, META, nmeta, GAINS, FLAGS, PAR, FFC, FFH, nffh, HL, MEAS, TRUTH):
    """The runs one after the other in the calling thread, without numba's thread pool (``threads=1``)."""
    for i in range(P.shape[0]):
        _batch_run(i, n, nsub, dsub, P, HARM, nh, closed, REF, OL, torque_limit, enc_step, JIT, NOISE, KNOM, SENS, SGAIN,
                   SOS, nsos, META, nmeta, GAINS, FLAGS, PAR, FFC, FFH, nffh, HL, MEAS, TRUTH)


def simulate_batch(runs: Sequence[BatchRun], *, duration_s: float, reference: Any = None, rate_hz: float = 2000.0,
                   substeps: int = 10, closed_loop: bool = True, threads: int | None = None,
                   **options: Any) -> BatchResult:
    """Simulate many runs of the testbed in one call, in parallel (numba ``prange``).

    Parameters
    ----------
    runs : sequence of BatchRun
        What differs per run: design (environment, controller, compensator), effects, seed,
        initial angle, optionally the reference.
    duration_s : float
        Length of every run [s].
    reference : Reference, callable or array, optional
        Reference of the runs that give none (see :func:`~.run.simulate`).
    rate_hz : float
        Control rate [Hz].
    substeps : int
        RK4 steps per period [-].
    closed_loop : bool
        Force control (True) or open-loop torque (False).
    threads : int, optional
        Threads of numba's pool for this call (default: numba's, i.e. every core). ``1`` runs
        the batch in the calling thread without the pool (e.g. in worker processes that already
        fill the cores); so does a call from any thread but the main one, since numba's fallback
        pool (workqueue) must not be entered by two threads at once. The results do not depend on it.
    **options
        The other options of :func:`~.run.simulate`, shared by every run:
        ``velocity_cutoff_hz``, ``sfm_deadband``, ``torque_limit``,
        ``encoder_counts``, ``encoder_jitter_counts``, ``process_noise_std``, ``include_nominal_viscous``,
        ``sfm_params``.

    Returns
    -------
    BatchResult
        Stacked logs; ``result(i)`` equals ``simulate(runs[i].design, effects=runs[i].effects,
        seed=runs[i].seed, initial_angle=runs[i].initial_angle, ...)`` exactly.

    Raises
    ------
    ParameterError
        No runs, an unknown option, or any error :func:`~.run.simulate` raises for a run
        (the message names the run).
    """
    runs = list(runs)
    if not runs:
        raise ParameterError("simulate_batch needs at least one run", name="runs", value=0)
    for key in options:
        if key not in SHARED_OPTIONS:
            raise ParameterError(f"unknown batch option {key!r}; allowed: {', '.join(SHARED_OPTIONS)}", name=key,
                                 value=options[key])
    if threads is not None:
        import numba

        if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= numba.config.NUMBA_NUM_THREADS:
            raise ParameterError(f"threads must be an integer in 1..{numba.config.NUMBA_NUM_THREADS}, got {threads!r}",
                                 name="threads", value=threads)
    prepared: list[_Prepared] = []
    for i, run in enumerate(runs):
        if i == 1:      # the first run gave the samples per run: bound the whole batch before the others
            check_limit(f"batch of {len(runs)} runs x {prepared[0].n} samples", "batch_samples",
                        len(runs) * prepared[0].n)
        if not isinstance(run, BatchRun):
            raise ParameterError(f"run {i} must be a BatchRun, got {type(run).__name__}", name="runs", value=i)
        ref = run.reference if run.reference is not None else reference
        if ref is None:
            raise ParameterError(f"run {i} has no reference and the batch gives none", name="reference", value=i)
        try:
            prepared.append(_prepare(run.design, reference=ref, duration_s=duration_s, effects=tuple(run.effects),
                                     rate_hz=rate_hz, substeps=substeps, seed=run.seed, closed_loop=closed_loop,
                                     initial_angle=run.initial_angle, description=run.description, **options))
        except ParameterError as exc:
            raise ParameterError(f"run {i}: {exc}", name=exc.name, value=exc.value) from None
    n = prepared[0].n
    meas = np.empty((len(runs), n, len(_MEAS)))
    truth = np.empty((len(runs), n, len(_TRUTH)))
    faults: list = [None] * len(runs)
    # controllers written as code run their own period loop, one run at a time (.code); the rest
    # go through the compiled kernel together
    for i, p in enumerate(prepared):
        if p.is_code:
            faults[i] = run_code(p, meas[i], truth[i])
    compiled = [i for i, p in enumerate(prepared) if not p.is_code]
    if compiled:
        _compiled_batch([prepared[i] for i in compiled], meas, truth, compiled, substeps=substeps, threads=threads,
                        closed_loop=closed_loop)
    t = np.arange(n) / float(rate_hz)
    t.flags.writeable = False
    return BatchResult(t=t, measured=meas, true=truth, _prepared=tuple(prepared), faults=tuple(faults))


def _compiled_batch(prepared: list[_Prepared], meas_all: np.ndarray, truth_all: np.ndarray, where: list[int], *,
                    substeps: int, threads: int | None, closed_loop: bool) -> None:
    """The runs ``prepared`` through the compiled batch kernel, written into rows ``where`` of the logs."""
    first = prepared[0]
    n = first.n
    whole = len(where) == meas_all.shape[0]

    def arr(key: str) -> list[np.ndarray]:
        return [p.arrays[key] for p in prepared]

    P = np.stack(arr("p"))
    HARM, nh = _pad(arr("harm"), 1)            # harmonics: each run keeps its own count
    programs = [p.program_arrays() for p in prepared]   # sos, meta, gains, flags, par, ff_coef, ff_harm
    SOS, nsos = _pad([a[0] for a in programs], 0)       # sections and channels: each run keeps its own count
    META, nmeta = _pad([a[1] for a in programs], 0, np.int64)
    GAINS, _ = _pad([a[2][:, None] for a in programs], 0)
    FFH, nffh = _pad([a[6] for a in programs], 1)
    dsub = np.array([int(p.plant.delay_substeps) for p in prepared], dtype=np.int64)
    hl = np.array([history_length(int(substeps), d) for d in dsub], dtype=np.int64)
    knom = np.array([p.k_nominal for p in prepared])
    meas = meas_all if whole else np.empty((len(prepared), n, len(_MEAS)))
    truth = truth_all if whole else np.empty((len(prepared), n, len(_TRUTH)))
    args = (n, int(substeps), dsub, P, HARM, nh, bool(closed_loop), np.stack(arr("ref")), np.stack(arr("ol")),
            first.torque_limit, first.enc_step, np.stack(arr("jit")), np.stack(arr("noise")), knom, np.stack(arr("sens")), first.sensor_gain, SOS, nsos, META,
            nmeta,
            np.ascontiguousarray(GAINS[:, :, 0]), np.stack([a[3] for a in programs]),
            np.stack([a[4] for a in programs]), np.stack([a[5] for a in programs]), FFH, nffh, hl, meas, truth)
    for kernel in (_batch_run, _batch_serial, _batch_loop):
        _check_kernel_cache(kernel)
    if threads == 1 or len(prepared) == 1 or threading.current_thread() is not threading.main_thread():
        # numba's fallback thread pool (workqueue) must not be entered by two threads at once
        _batch_serial(*args)
    elif threads is None:
        _batch_loop(*args)
    else:
        import numba

        previous = numba.get_num_threads()
        numba.set_num_threads(threads)
        try:
            _batch_loop(*args)
        finally:
            numba.set_num_threads(previous)
    if not whole:
        meas_all[where] = meas
        truth_all[where] = truth


def scenario_runs(scenario: Scenario, repetitions: Sequence[int] | None = None) -> list[BatchRun]:
    """The repetitions of a scenario as batch runs (:meth:`~.scenario.Scenario.repetition`, the rule
    :meth:`~.scenario.Scenario.run` follows).

    Parameters
    ----------
    scenario : Scenario
        From :func:`~.scenario.load_scenario`.
    repetitions : sequence of int, optional
        Which repetitions (default all: ``range(scenario.repetition_count)``).
    """
    indices = range(scenario.repetition_count) if repetitions is None else repetitions
    runs = []
    for i in indices:
        rep = scenario.repetition(i)
        runs.append(BatchRun(design=scenario.design, effects=rep.effects, seed=rep.seed,
                             initial_angle=rep.initial_angle, description=rep.description))
    return runs


def simulate_scenario(scenario: Scenario, *, threads: int | None = None,
                      repetitions: Sequence[int] | None = None) -> BatchResult:
    """Every repetition of a scenario as one batch (:func:`scenario_runs`, :func:`simulate_batch`).

    Parameters
    ----------
    scenario : Scenario
        From :func:`~.scenario.load_scenario`.
    threads : int, optional
        Threads of numba's pool (default: every core).
    repetitions : sequence of int, optional
        Which repetitions (default all).

    Returns
    -------
    BatchResult
        ``result(k)`` equals ``scenario.run(repetitions[k])`` (``scenario.run(k)`` for all).
    """
    opts = {k: v for k, v in scenario.options.items() if k not in ("seed", "initial_angle", "duration_s", "substeps")}
    with scenario.naming_errors():      # an error names the scenario file, as every scenario error does
        return simulate_batch(scenario_runs(scenario, repetitions), duration_s=scenario.options["duration_s"],
                              reference=scenario.reference, rate_hz=scenario.rate_hz,
                              substeps=scenario.options.get("substeps", 10), closed_loop=scenario.closed_loop,
                              threads=threads, **opts)
