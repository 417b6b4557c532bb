"""The interface every feature front end (ORB, libviso2-style) implements.

Extraction is separate from matching so the features stage extracts each image once and reuses the result for
its feature count and for all four camera pairings of the two time steps it takes part in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


@dataclass(frozen=True)
class PairCounts:
    """Counts for one image pair (previous → current)."""

    n_features_prev: int
    n_features_cur: int
    n_matches: int  # putative matches before geometric verification
    n_inliers: int  # matches consistent with one fundamental matrix (the paper's NFM)


class FrontEnd(Protocol):
    #: "orb" or "viso" (the `frontend` column of features/matches tables)
    name: str

    def extract(self, grey: np.ndarray) -> Any:
        """Detect and describe features on an 8-bit grey image (H×W uint8)."""

    def n_features(self, extracted: Any) -> int:
        """Number of detected features in one extracted image (the `features` table's n_features)."""

    def match(self, prev: Any, cur: Any, seed: int) -> tuple[int, int]:
        """Match two extracted images; return (n_matches, n_inliers). Deterministic for a given seed."""
