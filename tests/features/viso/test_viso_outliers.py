"""Delaunay outlier filter (spec §7): support counting per triangle edge and the support >= 4 rule."""

import numpy as np

from expoctl.features.viso.outliers import delaunay_support, remove_outliers

# a square with an interior point: the Delaunay triangulation is the unique fan of 4 triangles around the centre
CUR = np.array([[0, 0], [100, 0], [100, 100], [0, 100], [50, 50]])


def _matches(flows):
    cur = CUR
    prev = cur - np.asarray(flows)
    return np.hstack([prev, cur]).astype(np.int32)


def test_support_counts_each_edge_once_per_adjacent_triangle():
    m = _matches([(3, 1)] * 5)
    # centre: 4 spokes, each shared by 2 triangles → 8; a corner: its spoke (2) + two hull edges (1 each) → 4
    assert delaunay_support(m, 5).tolist() == [4, 4, 4, 4, 8]
    assert len(remove_outliers(m, 5)) == 5


def test_an_inconsistent_corner_removes_support_from_its_neighbours():
    flows = [(3, 1)] * 5
    flows[0] = (3 + 4, 1 + 1)  # L1 difference 5: not < 5, so inconsistent
    m = _matches(flows)
    # bad corner 0: 0; its hull neighbours 1 and 3: spoke 2 + one good hull edge → 3; opposite corner 2: 4; centre 6
    assert delaunay_support(m, 5).tolist() == [0, 3, 4, 3, 6]
    kept = remove_outliers(m, 5)
    assert kept.tolist() == m[[2, 4]].tolist()
    # a tolerance of 6 accepts the L1 difference of 5
    assert delaunay_support(m, 6).tolist() == [4, 4, 4, 4, 8]


def test_three_or_fewer_matches_skip_the_filter():
    m = _matches([(0, 0), (50, 0), (0, 70), (9, 9), (1, 1)])[:3]
    assert remove_outliers(m, 5).tolist() == m.tolist()


def test_collinear_points_have_no_triangles_and_no_support():
    cur = np.array([[0, 0], [10, 0], [20, 0], [30, 0], [40, 0]])
    m = np.hstack([cur, cur]).astype(np.int32)
    assert delaunay_support(m, 5).tolist() == [0] * 5
    assert len(remove_outliers(m, 5)) == 0
