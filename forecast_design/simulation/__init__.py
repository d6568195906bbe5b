"""The virtual testbed: true plant with unmodelled effects, 2 kHz controllers, references, runs, scenarios."""

from .plant import PlantModel, PlantStepper, TorqueSensor, build_plant, integrate_open_loop, stability_check
from .references import (
    REFERENCE_KINDS,
    Chirp,
    Constant,
    Multisine,
    PiecewiseLinear,
    Ramp,
    Sine,
    Square,
    Step,
    reference_from_mapping,
)
from .run import ENCODER_COUNTS, SimulationResult, SimulationTruth, save_simulation, simulate, plant_stepper

__all__ = [
    "simulate",
    "save_simulation",
    "SimulationResult",
    "SimulationTruth",
    "ENCODER_COUNTS",
    "PlantModel",
    "PlantStepper",
    "TorqueSensor",
    "plant_stepper",
    "build_plant",
    "integrate_open_loop",
    "stability_check",
    "Constant",
    "Step",
    "Square",
    "Sine",
    "Multisine",
    "Chirp",
    "Ramp",
    "PiecewiseLinear",
    "REFERENCE_KINDS",
    "reference_from_mapping",
]
