"""Force loops built once: the sampled-data loop at the control rate (and, to come, the continuous loop).

See :mod:`forecast_design.loops.sampled`.
"""

from .sampled import SampledForceLoop, ZohPlant, sampled_force_loop, to_w, zoh_plant

__all__ = ["SampledForceLoop", "sampled_force_loop", "ZohPlant", "zoh_plant", "to_w"]
