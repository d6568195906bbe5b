"""Force loops built in one place: the continuous loop and the sampled-data loop at the control rate.

See :mod:`forecast_design.loops.continuous` and :mod:`forecast_design.loops.sampled`.
"""

from .closing import BREAK_POINTS, ObservedPlant, close_loop
from .continuous import ForceLoop, force_loop, observed_plant
from .sampled import COMMAND_DELAY_SAMPLES, SampledForceLoop, ZohPlant, law_in_w, sampled_force_loop, to_w, zoh_plant

__all__ = ["ForceLoop", "force_loop", "observed_plant", "BREAK_POINTS", "ObservedPlant", "close_loop", "COMMAND_DELAY_SAMPLES", "SampledForceLoop",
           "sampled_force_loop", "ZohPlant", "zoh_plant", "to_w", "law_in_w"]
