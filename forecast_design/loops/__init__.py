"""Force loops built in one place: the continuous loop and the sampled-data loop at the control rate.

See :mod:`forecast_design.loops.continuous` and :mod:`forecast_design.loops.sampled`.
"""

from .continuous import BREAK_POINTS, ForceLoop, force_loop
from .sampled import SampledForceLoop, ZohPlant, sampled_force_loop, to_w, zoh_plant

__all__ = ["ForceLoop", "force_loop", "BREAK_POINTS", "SampledForceLoop", "sampled_force_loop", "ZohPlant",
           "zoh_plant", "to_w"]
