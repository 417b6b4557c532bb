"""The libviso2-style feature front end (clean room; docs/features.md), one module per step.

`frontend` (extract, match, count: the `VisoFrontEnd`), `params` (the `features.viso` config), `filters` (Sobel,
blob and corner responses), `nms`, `descriptors`, `match` (circle matching, flow prior, refinement), `sad`,
`outliers` (Delaunay filter) and `ransac` (F-RANSAC, bucketing).
"""

from expoctl.features.viso.frontend import (VisoCounts, VisoFeatures, VisoFrontEnd, extract_features, match_matches,
                                            pair_counts)
from expoctl.features.viso.params import VisoParams, parse_params

__all__ = ["VisoCounts", "VisoFeatures", "VisoFrontEnd", "VisoParams", "extract_features", "match_matches",
           "pair_counts", "parse_params"]
