"""Feature front ends and the counts the labels are made of: the features stage and the front-end factory
(`pipeline`), ORB (`orb`), the libviso2-style front end (`viso`, imported only when asked for: it is the heavier
package), fundamental-matrix verification (`verify`), SumLog (`sumlog`) and the `expoctl match` command (`match_cli`).
"""

from expoctl.features.orb import OrbFrontEnd, OrbParams
from expoctl.features.pipeline import (FeaturesConfig, compute_features, iter_training_pairs_rgb,
                                       rgb_to_grey)
from expoctl.features.registry import FRONTENDS, frontend_names, make_frontend, register_frontend
from expoctl.features.sumlog import SumLogParams, sumlog_uint8, tune_sumlog

__all__ = ["FRONTENDS", "FeaturesConfig", "frontend_names", "register_frontend", "OrbFrontEnd", "OrbParams", "SumLogParams", "compute_features", "iter_training_pairs_rgb",
           "make_frontend", "rgb_to_grey", "sumlog_uint8", "tune_sumlog"]
