"""Camera poses through a city's first tunnel for renderer comparison tests (import: `from render_poses import ...`)."""

import numpy as np

UP = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)  # camera rotations applied to a lane pose
LEFT = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], float)
BACK = np.array([[-1, 0, 0], [0, 1, 0], [0, 0, -1]], float)


def tunnel_poses(city, portal_offset_m: float = 1.0) -> list[np.ndarray]:
    """Open road, approach, `portal_offset_m` before the portal, just inside, deep inside looking at the exit, and
    turned views (roadside props and blocks, the tunnel ceiling, the portal face behind)."""
    t = city.cfg["tunnels"][0]
    start, length = float(t["start_m"]), float(t["length_m"])
    poses = [city.pose_at_s(s, 0.0) for s in (250.0, start - 20.0, start - portal_offset_m, start + 2.0,
                                              start + length - 25.0)]
    for s, m in ((250.0, LEFT), (start + 30.0, UP), (start - 3.0, BACK), (330.0, LEFT)):
        p = city.pose_at_s(s, 0.0)
        p[:3, :3] = p[:3, :3] @ m
        poses.append(p)
    return poses
