"""Monocular visual odometry for the tracking-success test: frame to frame (`frame_to_frame`) and against a local map
with ORB-SLAM2's tracking thresholds (`local_map`).
"""

from expoctl.vo.frame_to_frame import intrinsics_matrix, track_sequence
from expoctl.vo.local_map import MapTracker, MapTrackerConfig

__all__ = ["MapTracker", "MapTrackerConfig", "intrinsics_matrix", "track_sequence"]
