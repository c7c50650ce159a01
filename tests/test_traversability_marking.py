"""Grid-mode cell marking of the traversability metrics: pbdyn's "centre_inside" vs the thesis program's rule
(pbdyn.metrics.traversability module doc): centre inside-or-on a disc for the freshly built map (traversability),
the floor(r / cell) square for stepped maps (dynamic traversability); the program's wall cells lie outside the
arena (the thesis scenarios' 48 m arena is the space between them)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pbdyn.errors import ConfigError
from pbdyn.metrics.registry import compute, parameters
from pbdyn.metrics.traversability import blocked_cells, dynamic_traversability, traversability
from pbdyn.world.rollout import Rollout

SQ2 = math.sqrt(2.0)


def still(centres, radii, size=(50.0, 50.0)) -> Rollout:
    """Obstacles at rest at ``centres`` for 20 s (dt 0.1)."""
    size = np.asarray(size, float)
    c = np.asarray(centres, float).reshape(-1, size.shape[0])
    times = np.arange(201) * 0.1
    pos = np.repeat(c[None], times.shape[0], axis=0)
    return Rollout(times, pos, np.zeros_like(pos), np.asarray(radii, float), size, 0.1, (), {})


def cells(mask: np.ndarray) -> set[tuple[int, ...]]:
    return {tuple(int(v) for v in ix) for ix in np.argwhere(mask)}


def test_the_three_cell_rules_on_hand_placed_discs():
    # a: r 0.4 off its cell centre by (0.3, 0.3): no cell centre within it, but its cell is its "home";
    # b: r 1.2 on a cell centre: the centre and 4 side neighbours (diagonals at 1.41 m), square 3 x 3;
    # c: r 1.0 on a cell centre: the side neighbours lie exactly on the disc (excluded by <, included by <=).
    ro = still([[10.2, 10.2], [20.5, 20.5], [30.5, 30.5]], [0.4, 1.2, 1.0])
    plus = lambda i, j: {(i, j), (i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)}     # noqa: E731
    square = lambda i, j: {(i + a, j + b) for a in (-1, 0, 1) for b in (-1, 0, 1)}     # noqa: E731
    centre = blocked_cells(ro, 0, 1.0)
    assert centre.shape == (50, 50)
    assert cells(centre) == plus(20, 20) | {(30, 30)}
    reset = blocked_cells(ro, 0, 1.0, rule="program_reset")
    assert cells(reset) == plus(20, 20) | plus(30, 30)
    step = blocked_cells(ro, 0, 1.0, rule="program_step")
    assert cells(step) == {(10, 10)} | square(20, 20) | square(30, 30)
    with pytest.raises(ConfigError) as e:
        blocked_cells(ro, 0, 1.0, rule="program")
    assert e.value.field == "rule"


def test_square_reach_is_floor_of_radius_over_cell_and_is_clipped_at_the_border():
    ro = still([[0.5, 25.5], [25.7, 25.2]], [1.5, 2.0])
    step = blocked_cells(ro, 0, 1.0, rule="program_step")
    inner = cells(step)
    left = {(i, j) for i in (0, 1) for j in (24, 25, 26)}              # reach 1 around (0, 25), clipped at i = 0
    big = {(i, j) for i in range(23, 28) for j in range(23, 28)}       # reach 2 around (25, 25)
    assert inner == left | big


def test_walks_differ_by_the_marking():
    ro = still([[28.5, 26.5]], [1.2])
    start = [[25.5, 25.5]]
    # directions: E, NE, N, NW, W, SW, S, SE
    cur = traversability(ro, starts=start, mode="grid")
    prog = traversability(ro, starts=start, mode="grid", marking="program")
    dyn_cur = dynamic_traversability(ro, starts=start, mode="grid", times=(0.0, 5.0))
    dyn_prog = dynamic_traversability(ro, starts=start, mode="grid", marking="program", times=(0.0, 5.0))
    # centre_inside: disc cells (28, 26) +- 1 side; E along row 25 stops at (28, 25); W runs out of the grid
    np.testing.assert_allclose(cur.per_sample[0], [2, 24 * SQ2, 24, 24 * SQ2, 25, 25 * SQ2, 25, 24 * SQ2])
    # program, fresh map: the same disc cells (none on the circle here), so the same walks
    np.testing.assert_allclose(prog.per_sample[0], cur.per_sample[0])
    # program, stepped map: the 3 x 3 square x 27..29, y 25..27 blocks (27, 25) E and (27, 27) NE
    np.testing.assert_allclose(dyn_prog.per_sample[0, 0], [1, SQ2, 24, 24 * SQ2, 25, 25 * SQ2, 25, 24 * SQ2])
    np.testing.assert_allclose(dyn_cur.per_sample[0, 0], cur.per_sample[0])
    assert dyn_prog.value < prog.value
    assert cur.params["marking"] == "centre_inside" and prog.params["marking"] == "program"
    assert dyn_prog.params["marking"] == "program" and dyn_cur.params["marking"] == "centre_inside"


def test_marking_is_a_registry_parameter_with_named_errors():
    ro = still([[28.5, 26.5]], [1.2])
    for name in ("traversability", "traversability_dense", "dynamic_traversability"):
        assert "marking" in parameters(name)
    dense = compute(ro, "traversability_dense", mode="grid", marking="program")
    assert dense.params["marking"] == "program" and dense.n_samples == 81
    with pytest.raises(ConfigError) as e:
        traversability(ro, mode="grid", marking="truncate")
    assert e.value.field == "marking"
    with pytest.raises(ConfigError) as e:
        dynamic_traversability(ro, marking="program")          # exact mode has no cells
    assert e.value.field == "marking"


def test_program_marking_in_3d_uses_cubes():
    ro = still([[25.5, 25.5, 10.5]], [1.0], size=(50.0, 50.0, 20.0))
    step = blocked_cells(ro, 0, 1.0, rule="program_step")
    assert step.shape == (50, 50, 20)
    inner = {tuple(v) for v in np.argwhere(step).tolist()}
    assert inner == {(25 + a, 25 + b, 10 + c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)}
