"""Closed-loop model selection: which network the pipeline hands to evaluation (`model_selection`), with the
saturation probe of a controller's fixed points (`saturation_probe`)."""
