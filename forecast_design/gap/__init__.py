"""Sim-to-real gap diagnosis: where a log departs from the nominal model, which effect explains it, how far the gap shrinks."""

from .bench import BenchCase, BenchResult, benchmark
from .candidates import CANDIDATE_EFFECTS, CandidateFit, JointAttribution, fit_joint, fit_pair
from .diagnose import Diagnosis, RankedCandidate, diagnose, held_out_test
from .locate import Location, empirical_response, locate_gap
from .replay import ReplayCheck, replay_check, replay_trace
from .report import write_report
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
