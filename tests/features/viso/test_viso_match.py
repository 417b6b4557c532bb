"""Flow matching (spec §6): circle check, lookup windows and quirks, tie order, prior, integer refinement."""

import numpy as np
import pytest

from expoctl.features.viso.filters import sobel_du_dv
from expoctl.features.viso.match import Grid, circle_match, flow_prior, make_feature_set, refine_integer

GRID = Grid(640, 480, 50)
R = 100.0


def _desc(value):
    return np.full(32, value, np.uint8)


def _fs(points):
    """points: list of (u, v, class, descriptor byte value or 32-byte array)."""
    u = np.array([p[0] for p in points], np.int32)
    v = np.array([p[1] for p in points], np.int32)
    c = np.array([p[2] for p in points], np.int8)
    d = np.stack([p[3] if isinstance(p[3], np.ndarray) else _desc(p[3]) for p in points])
    return make_feature_set(u, v, c, d, GRID)


def _rows(m):
    return [tuple(r) for r in m.tolist()]


def test_mutual_best_matches_are_kept():
    cur = _fs([(100, 100, 1, 10), (300, 300, 1, 200)])
    prev = _fs([(302, 302, 1, 201), (104, 98, 1, 10)])
    assert _rows(circle_match(prev, cur, GRID, R, None)) == [(104, 98, 100, 100), (302, 302, 300, 300)]


def test_circle_check_rejects_a_non_mutual_match():
    # cur 0 → prev 0, but prev 0 → cur 1 (closer descriptor), so only cur 1 is matched
    cur = _fs([(100, 100, 1, 20), (110, 100, 1, 12)])
    prev = _fs([(105, 100, 1, 10)])
    assert _rows(circle_match(prev, cur, GRID, R, None)) == [(105, 100, 110, 100)]


def test_only_the_same_class_is_a_candidate():
    cur = _fs([(100, 100, 1, 10), (400, 400, 2, 50)])
    prev = _fs([(400, 400, 2, 50), (102, 100, 0, 10), (120, 100, 1, 90)])  # identical descriptor but class 0
    assert _rows(circle_match(prev, cur, GRID, R, None)) == [(120, 100, 100, 100), (400, 400, 400, 400)]


def test_one_match_per_current_pixel():
    # a blob and a corner feature at the same pixel both pass the circle check; only the first is accepted
    cur = _fs([(100, 100, 0, 10), (100, 100, 2, 60)])
    prev = _fs([(102, 100, 0, 10), (102, 100, 2, 60)])
    assert _rows(circle_match(prev, cur, GRID, R, None)) == [(102, 100, 100, 100)]


def test_window_is_inclusive_and_no_candidate_returns_index_0():
    # prev at exactly +R: inside the window, matched to cur 1
    cur = _fs([(500, 400, 1, 200), (100, 100, 1, 10)])
    assert _rows(circle_match(_fs([(200, 100, 1, 10)]), cur, GRID, R, None)) == [(200, 100, 100, 100)]
    # one pixel further: cur 1 finds nothing (→ prev 0, whose back-search finds nothing → cur 0 ≠ 1), while cur 0
    # finds nothing either (→ prev 0 → back-search empty → index 0 == 0): libviso2 accepts that spurious match
    assert _rows(circle_match(_fs([(201, 100, 1, 10)]), cur, GRID, R, None)) == [(201, 100, 500, 400)]


def test_equal_cost_ties_follow_cell_order_then_index():
    cur = _fs([(120, 120, 1, 10)])
    # prev 0 is in u-cell 3, prev 1 in u-cell 2: equal SAD, the lower u-cell wins despite the higher index
    prev = _fs([(160, 110, 1, 10), (110, 130, 1, 10)])
    assert _rows(circle_match(prev, cur, GRID, R, None)) == [(110, 130, 120, 120)]
    # same cell: the lower index wins
    prev = _fs([(112, 112, 1, 10), (110, 110, 1, 10)])
    assert _rows(circle_match(prev, cur, GRID, R, None)) == [(112, 112, 120, 120)]


def test_prior_widening_and_neighbourhood():
    # one sparse match: cur (120, 80) in cell (2, 1), flow prev − cur = (+10, −10)
    prior = flow_prior(np.array([[130, 70, 120, 80]], np.int32), GRID, R).reshape(GRID.n_u, GRID.n_v, 8)
    assert prior.shape == (13, 10, 8)
    # width 0 < 20: widened by ceil(20 / 2) = 10 at both ends; bwd is the negated fwd range
    assert prior[2, 1].tolist() == [0, 20, -20, 0, -20, 0, 0, 20]
    assert prior[1, 0].tolist() == prior[3, 2].tolist() == prior[2, 1].tolist()  # 3×3 neighbourhood
    assert prior[4, 1].tolist() == [-R, R] * 4  # outside: empty cell
    assert prior[2, 3].tolist() == [-R, R] * 4


def test_prior_ranges_of_several_matches():
    m = np.array([[110, 100, 100, 100], [140, 130, 100, 110], [157, 99, 110, 105]], np.int32)
    prior = flow_prior(m, GRID, R).reshape(GRID.n_u, GRID.n_v, 8)
    # fwd u deltas 10, 40, 47 → [10, 47] (width 37, kept); v deltas 0, 20, −6 → [−6, 20] (width 26, kept)
    assert prior[2, 2].tolist() == [10, 47, -6, 20, -47, -10, -20, 6]
    # width 15 (odd, from deltas 10 and 25) grows by ceil(2.5) = 3 at both ends
    p2 = flow_prior(np.array([[110, 100, 100, 100], [125, 100, 100, 100]], np.int32), GRID, R)
    assert p2.reshape(GRID.n_u, GRID.n_v, 8)[2, 2, :2].tolist() == [7, 28]


def test_prior_restricts_both_search_stages():
    cur = _fs([(100, 100, 1, 10)])
    prev = _fs([(140, 100, 1, 10)])
    # prior allows prev − cur in [−10, 10] only: the true candidate (+40) is outside
    prior = np.tile([-10, 10, -10, 10, -10, 10, -10, 10], (GRID.n_u * GRID.n_v, 1)).astype(float)
    # stage 0 finds nothing → prev 0; stage 1 from prev 0 searches [130, 150]: nothing → cur 0 == 0, accepted by the quirk
    assert len(circle_match(prev, cur, GRID, R, prior)) == 1
    cur2 = _fs([(400, 400, 1, 200), (100, 100, 1, 10)])
    # the true pair is still out of reach; only the quirk pairs cur 0 with prev 0 (both searches empty)
    assert _rows(circle_match(prev, cur2, GRID, R, prior)) == [(140, 100, 400, 400)]
    # a prior admitting +40 in u: cur 1 matches; cur 0's back-search (with cur 0's cell prior) now finds cur 1 ≠ 0
    prior[:, [0, 1, 4, 5]] = [30, 50, -50, -30]
    assert _rows(circle_match(prev, cur2, GRID, R, prior)) == [(140, 100, 100, 100)]


def test_integer_refinement_moves_only_the_previous_position():
    rng = np.random.default_rng(0)
    prev_img = rng.integers(0, 256, (60, 80), dtype=np.uint8)
    # content moves by (+3, −2): cur(x, y) = prev(x − 3, y + 2)
    cur_img = np.zeros_like(prev_img)
    cur_img[:-2, 3:] = prev_img[2:, :-3]
    du_p, dv_p = sobel_du_dv(prev_img)
    du_c, dv_c = sobel_du_dv(cur_img)
    uc, vc = 40, 30
    true_prev = (uc - 3, vc + 2)
    m = np.array([[true_prev[0] + 1, true_prev[1] - 2, uc, vc], [10, 30, uc, vc]], np.int32)
    out = refine_integer(m, du_p, dv_p, du_c, dv_c, margin=9)
    assert tuple(out[0]) == (true_prev[0], true_prev[1], uc, vc)
    # u − 2 = 8 < 9: a shift would come too close to the border, so the match stays unrefined
    assert tuple(out[1]) == (10, 30, uc, vc)


@pytest.mark.parametrize("u,ok", [(11, True), (10, False), (68, True), (69, False)])
def test_refinement_border_rule(u, ok):
    # width 80: refine only when u − 2 >= 9 and u + 2 <= 80 − 10
    du = np.zeros((60, 80), np.uint8)
    dv = np.zeros((60, 80), np.uint8)
    du_c = du.copy()
    du_c[30, 40] = 255  # the reference has a bright centre; the previous image is flat except one pixel
    du_p = du.copy()
    du_p[31, u + 1] = 255  # best shift (+1, +1)
    out = refine_integer(np.array([[u, 30, 40, 30]], np.int32), du_p, dv, du_c, dv, margin=9)
    assert tuple(out[0, :2]) == ((u + 1, 31) if ok else (u, 30))
