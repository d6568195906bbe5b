"""Sim-to-real gap diagnosis: where a log departs from the nominal model, which effect explains it, how far the gap shrinks."""

from .bench import BenchCase, BenchResult, benchmark
from .candidates import CANDIDATE_EFFECTS, CandidateFit, fit_pair
from .joint import JointAttribution, fit_joint
from .diagnose import Diagnosis, RankedCandidate, diagnose, held_out_test
from .locate import Location, empirical_response, locate_gap
from .replay import ReplayCheck, replay_check, replay_trace
from .residuals import GapData, GapOptions, prepare_gap_data

__all__ = [
    "diagnose",
    "Diagnosis",
    "RankedCandidate",
    "held_out_test",
    "GapOptions",
    "GapData",
    "prepare_gap_data",
    "CandidateFit",
    "CANDIDATE_EFFECTS",
    "JointAttribution",
    "fit_joint",
    "fit_pair",
    "Location",
    "locate_gap",
    "empirical_response",
    "write_report",
    "ReplayCheck",
    "replay_check",
    "replay_trace",
    "benchmark",
    "BenchResult",
    "BenchCase",
]


def __getattr__(name: str):
    # write_report moved to forecast_design.reporting (it draws, a layer above the diagnosis);
    # resolved there on use for one release
    if name == "write_report":
        import importlib

        return importlib.import_module(__name__.rsplit(".", 1)[0] + ".reporting").write_report
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
