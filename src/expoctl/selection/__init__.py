"""Closed-loop model selection: which network the pipeline hands to evaluation (`model_selection`), with the
saturation probe of a controller's fixed points (`saturation_probe`).
"""

from expoctl.selection.model_selection import Candidate, SelectConfig, probe_candidates, probe_filter, select_model
from expoctl.selection.saturation_probe import summary_line

__all__ = ["Candidate", "SelectConfig", "probe_candidates", "probe_filter", "select_model", "summary_line"]
