"""Monocular visual odometry for the tracking-success test: frame to frame (`frame_to_frame`) and against a local map
with ORB-SLAM2's tracking thresholds (`local_map`)."""
