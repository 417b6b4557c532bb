"""The closed-loop camera simulator: the rig loop with its one-frame actuation latency (`closed_loop`), the paper's
perturbation of camera 2 (`protocol`), data collection (`collect`; its entry point `collect.collect` keeps its
module's name, so it is not re-exported here), previews (`preview`, the `expoctl preview` command), the exposure
sweep (`exposure_sweep`) and the oracle (`oracle`: it renders the scene, so it lives with the simulator, not with
the causal controllers).
"""

from expoctl.sim.closed_loop import (CameraFrame, RenderConfig, RigConfig, RigFrame, RouteScene, drive_rig,
                                     make_sensors, rig_metadata, run_closed_loop)
from expoctl.sim.collect import derive_seed
from expoctl.sim.oracle import OracleParams
from expoctl.sim.protocol import PerturbationConfig

__all__ = ["CameraFrame", "OracleParams", "PerturbationConfig", "RenderConfig", "RigConfig", "RigFrame", "RouteScene",
           "derive_seed", "drive_rig", "make_sensors", "rig_metadata",
           "run_closed_loop"]
