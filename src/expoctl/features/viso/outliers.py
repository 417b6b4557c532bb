"""Delaunay outlier filter of the libviso2-style matcher (spec §7, removeOutliers for flow)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay, QhullError

#: Minimum number of consistent Delaunay edges (counted once per adjacent triangle) a match needs to survive.
MIN_SUPPORT = 4


def delaunay_support(matches: np.ndarray, flow_tolerance: float) -> np.ndarray:
    """Support count per match: over the triangles of the Delaunay triangulation of the current positions, each edge
    whose endpoints' flows (cur − prev) differ by less than `flow_tolerance` in L1 adds 1 to both endpoints."""
    n = len(matches)
    pts = matches[:, 2:4].astype(np.float64)
    try:
        simplices = Delaunay(pts).simplices
    except QhullError:
        # all points collinear (or otherwise degenerate): no triangles, so no support
        return np.zeros(n, np.int64)
    flow = (matches[:, 2:4] - matches[:, 0:2]).astype(np.float64)
    support = np.zeros(n, np.int64)
    for e0, e1 in ((0, 1), (1, 2), (2, 0)):
        a = simplices[:, e0]
        b = simplices[:, e1]
        consistent = np.abs(flow[a] - flow[b]).sum(axis=1) < flow_tolerance
        support += np.bincount(a[consistent], minlength=n)
        support += np.bincount(b[consistent], minlength=n)
    return support


def remove_outliers(matches: np.ndarray, flow_tolerance: float) -> np.ndarray:
    """Matches with Delaunay support >= MIN_SUPPORT; with 3 matches or fewer the filter is skipped."""
    if len(matches) <= 3:
        return matches
    return matches[delaunay_support(matches, flow_tolerance) >= MIN_SUPPORT]
