"""Hardware runtime: the board protocol, the serial link, the host-side Board and a board emulator."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from ..environments import resolve_environments, resolve_testbed
from ..params import Design

from .board import Board, RunResult, check_writable, record_to_experiment
from .emulator import Faults, emulate, open_pty, parse_fault, serve_emulator
from .link import BoardError, Link, LinkError
from .protocol import BAUD_RATE, FrameParser, Reference, encode_frame, parse_reference, stream_bits_per_second

__all__ = [
    "Board",
    "BoardError",
    "check_writable",
    "LinkError",
    "Link",
    "RunResult",
    "Faults",
    "FrameParser",
    "Reference",
    "BAUD_RATE",
    "emulate",
    "encode_frame",
    "open_pty",
    "parse_fault",
    "parse_reference",
    "record_to_experiment",
    "run_on_port",
    "serve_emulator",
    "stream_bits_per_second",
]


def run_on_port(port: str, *, out: str | Path, reference: str | Reference = "square:0.2:0.5",
                duration: float = 5.0, controller: str = "pd:5:0.1", compensator: str = "none",
                w_q_hz: float = 10.0, env: Any = "exp-soft", sfm_params: Mapping[str, float] | None = None,
                timeout: float = 1.0, baudrate: int = BAUD_RATE, testbed: Any = None) -> RunResult:
    """The ``forecast-design run`` verb: export, upload, record, save.

    Parameters
    ----------
    port : str
        Serial device, pty path or pyserial URL.
    out : str or Path
        Experiment TOML to write (CSV beside it).
    reference : str or Reference
        ``square:AMP:PERIOD``, ``sine:AMP:PERIOD`` or ``step:AMP[:DELAY]`` [N m, s].
    duration : float
        Run length [s].
    controller : str
        ``pd:P:D``.
    compensator : str
        none | sfm | ea-fob | lo-dob | ld-dob | motor-fob.
    w_q_hz : float
        Q cutoff of the observers [Hz].
    env : Environment, str or EnvironmentSet
        The one environment of the nominal model (written to the TOML): an Environment, a preset
        name, inline ``k_e=..,J_e=..`` values or a file holding one
        (:func:`~forecast_design.environments.resolve_environments`; a set of several is an error).
    sfm_params : Mapping[str, float], optional
        Identified SFM parameters (compensator ``sfm``).
    timeout : float
        Silence that counts as a disconnect [s].
    baudrate : int
        UART rate [bit/s].
    testbed : Testbed, str or None
        The testbed of the nominal model (:func:`~forecast_design.environments.resolve_testbed`:
        inline ``k=40``, a TOML file with ``[testbed]``, a run's or a scenario's TOML); None: Table 1.

    Returns
    -------
    RunResult
        ``to_mapping()`` is the summary JSON {"samples", "lost", "corrupt_frames", "resyncs", ...}.

    Raises
    ------
    ParameterError
        Bad controller/compensator/reference strings.
    LinkError
        Disconnect or silence mid-run (after saving what was received).
    """
    from ..export.c import program_for_export
    from ..params import resolve_design

    ref = parse_reference(reference) if isinstance(reference, str) else reference
    check_writable(out)  # before the board is touched: a run is never recorded only to be lost
    tb = resolve_testbed(testbed)
    env = resolve_environments(env, testbed=tb).single("run_on_port")[1]
    design = resolve_design(Design(testbed=tb, environment=env), controller=controller, compensator=compensator,
                            w_q_hz=w_q_hz)
    program = program_for_export(design.with_friction(sfm_params))
    with Board(port, baudrate=baudrate, timeout=timeout) as board:
        board.ping()
        board.upload(program)
        return board.run(ref, duration, design, out)


