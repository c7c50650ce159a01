"""The occupancy grid: layout with a wall border, sticky OCCUPIED, exact clearance to occupied cells."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.perception.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid


def test_layout_includes_a_one_cell_border():
    g = OccupancyGrid([0, 0], [50, 50], 1.0)
    assert g.shape == (52, 52)
    assert tuple(g.index(np.array([0.5, 49.5]))) == (1, 50)
    assert tuple(g.index(np.array([-0.5, 50.5]))) == (0, 51)
    assert np.all(g.cells == UNKNOWN) and g.discovered() == 0


def test_occupied_is_sticky_and_free_marks_the_rest():
    g = OccupancyGrid([0, 0], [10, 10], 1.0)
    g.mark_occupied(np.array([[5.5, 5.5]]))
    g.mark_free(np.array([[5.2, 5.7], [3.5, 3.5]]))
    assert g.value_at(np.array([5.5, 5.5])) == OCCUPIED
    assert g.value_at(np.array([3.5, 3.5])) == FREE
    assert g.discovered() == 2


def test_clearance_is_exact_point_to_square_distance():
    g = OccupancyGrid([0, 0], [10, 10], 1.0)
    g.mark_occupied(np.array([[5.5, 5.5]]))              # the square [5, 6] x [5, 6]
    pts = np.array([[5.5, 5.5], [7.0, 5.5], [7.0, 7.0], [5.5, 3.0], [9.0, 9.0]])
    d = g.clearance(pts, max_dist=2.0)
    np.testing.assert_allclose(d, [0.0, 1.0, np.sqrt(2.0), 2.0, 2.0])
    assert list(g.collides(pts, 1.0)) == [True, False, False, False, False]
    assert list(g.collides(pts, 1.5)) == [True, True, True, False, False]


def test_clearance_3d():
    g = OccupancyGrid([0, 0, 0], [10, 10, 10], 1.0)
    g.mark_occupied(np.array([[2.5, 2.5, 2.5]]))
    np.testing.assert_allclose(g.clearance(np.array([[4.0, 4.0, 4.0]]), 5.0), [np.sqrt(3.0)])


def test_clearance_skips_only_points_far_from_every_occupied_cell():
    """The near-occupied shortcut of clearance() gives exactly the full search's distances (2D and 3D, points
    inside and outside the grid, several caps), and follows direct writes to ``cells``."""
    rng = np.random.default_rng(3)
    for it in range(40):
        d = 2 if it % 2 else 3
        g = OccupancyGrid(np.zeros(d), np.full(d, 20.0 if d == 2 else 10.0), 1.0)
        g.cells[rng.random(g.shape) < rng.uniform(0.0, 0.03)] = OCCUPIED
        pts = rng.uniform(-3.0, (23.0 if d == 2 else 13.0), size=(300, d))
        for cap in (0.5, 1.5, 2.5, 3.7):
            assert np.array_equal(g.clearance(pts, cap), g._clearance_search(pts, g.index(pts), cap))
    g = OccupancyGrid(np.zeros(2), np.full(2, 20.0), 1.0)
    p = np.array([[10.5, 10.5]])
    assert g.clearance(p, 2.5)[0] == 2.5
    g.cells[12, 11] = OCCUPIED                        # a direct write: the cell [10, 11) x [9, 10) in world metres
    assert g.clearance(p, 2.5)[0] == pytest.approx(0.5)
    g.cells[12, 11] = FREE
    assert g.clearance(p, 2.5)[0] == 2.5


def clearance_reference(g: OccupancyGrid, pts: np.ndarray, cap: float) -> np.ndarray:
    """The reference twin of OccupancyGrid.clearance (m): the exact point-to-box distance to every OCCUPIED cell,
    capped at ``cap``: the definition, with no search."""
    cmin = g.origin + np.argwhere(g.cells == OCCUPIED) * g.res                        # [M, d]
    out = np.full(pts.shape[0], float(cap))
    if cmin.shape[0] == 0:
        return out
    delta = np.maximum(np.maximum(cmin[None] - pts[:, None], pts[:, None] - (cmin[None] + g.res)), 0.0)
    return np.minimum(out, np.sqrt(np.sum(delta * delta, axis=-1)).min(axis=1))


def test_clearance_equals_the_definition_bit_for_bit():
    """The pruned neighbourhood search gives exactly the distance to the nearest OCCUPIED box over all of them
    (2D and 3D, sparse to dense grids, points inside, outside and on cell faces, caps on and off cell multiples,
    resolutions other than 1 m)."""
    rng = np.random.default_rng(11)
    for it in range(60):
        d = 2 if it % 2 else 3
        res = (1.0, 0.5, 0.3)[it % 3]
        size = 12.0 if d == 2 else 6.0
        g = OccupancyGrid(np.zeros(d), np.full(d, size), res)
        g.cells[rng.random(g.shape) < rng.uniform(0.0, 0.2)] = OCCUPIED
        pts = rng.uniform(-2.0, size + 2.0, size=(400, d))
        pts[:50] = np.round(pts[:50] / res) * res                                   # on cell faces
        for cap in (0.4, 1.0, 1.5, 2.0, 2.5, 3.7):
            assert np.array_equal(g.clearance(pts, cap), clearance_reference(g, pts, cap)), (it, cap)
            assert np.array_equal(g.collides(pts, cap), clearance_reference(g, pts, cap + res) < cap)


def test_near_occupied_mask_equals_shift_or_dilation():
    """The compiled dilation behind clearance()'s shortcut equals numpy shift-ORs (2D and 3D, several reaches,
    occupied cells on the border), and the padded mask holds the OCCUPIED cells at an offset of ``reach``."""
    rng = np.random.default_rng(8)
    for it in range(30):
        d = 2 if it % 2 else 3
        g = OccupancyGrid(np.zeros(d), np.full(d, 15.0 if d == 2 else 7.0), 1.0)
        g.cells[rng.random(g.shape) < rng.uniform(0.002, 0.05)] = OCCUPIED
        g.cells[(0,) * d] = OCCUPIED
        occ = g.cells == OCCUPIED
        for h in (0, 1, 2, 3, 40):
            assert np.array_equal(g._near(h, occ, {}), OccupancyGrid._near_reference(h, occ)), (it, h)
        padded = g._padded(4, occ, {}).reshape(tuple(n + 8 for n in g.shape))
        assert np.array_equal(padded, np.pad(occ, 4))
