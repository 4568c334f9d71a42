"""nhstab's own Reeds-Shepp and Dubins local paths against OMPL's state spaces."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from nhstab.planning import local_paths

ompl_base = pytest.importorskip("ompl.base")


def _space(kind: str, radius: float):
    if kind == "reeds_shepp":
        return ompl_base.ReedsSheppStateSpace(radius)
    return ompl_base.DubinsStateSpace(radius, False)


def _set(state, pose):
    state.setX(float(pose[0]))
    state.setY(float(pose[1]))
    state.setYaw(float(pose[2]))


def _pairs(rng, n):
    a = np.column_stack([rng.uniform(-6, 6, (n, 2)), rng.uniform(-math.pi, math.pi, n)])
    b = np.column_stack([rng.uniform(-6, 6, (n, 2)), rng.uniform(-math.pi, math.pi, n)])
    near = np.arange(n) % 4 == 0                        # a quarter of the goals close to the start
    b[near, :2] = a[near, :2] + rng.uniform(-0.6, 0.6, (near.sum(), 2))
    return a, b


@pytest.mark.parametrize("kind", ["reeds_shepp", "dubins"])
def test_lengths_and_samples_match_ompl(kind):
    """Over 2000 seeded pose pairs (radius 1.3 m): the length equals OMPL's distance to 1e-12 m, and the
    samples at 7 fractions equal OMPL's interpolate to 1e-9 wherever OMPL chose the same word. Reeds-Shepp
    has exact ties between two words of equal length (a CCC word and its time-flipped reflection), which
    the two implementations may break differently by one rounding: at most 1 % of the pairs differ, and
    then only in the word, not in the length."""
    rng = np.random.default_rng(20260)
    radius = 1.3
    space = _space(kind, radius)
    sa, sb, tmp = space.allocState(), space.allocState(), space.allocState()
    a, b = _pairs(rng, 2000)
    fractions = np.linspace(0.0, 1.0, 7)
    differ = 0
    for p, q in zip(a, b):
        _set(sa, p)
        _set(sb, q)
        seg = local_paths.local_path(kind, p, q, radius)
        assert abs(local_paths.path_length(seg, radius) - space.distance(sa, sb)) < 1e-12
        ours = local_paths.sample(p, seg, radius, fractions)
        theirs = []
        for f in fractions:
            space.interpolate(sa, sb, float(f), tmp)
            theirs.append((tmp.getX(), tmp.getY(), tmp.getYaw()))
        theirs = np.array(theirs)
        d = np.abs(ours[:, :2] - theirs[:, :2]).max()
        dth = np.abs((ours[:, 2] - theirs[:, 2] + math.pi) % (2 * math.pi) - math.pi).max()
        if d > 1e-9 or dth > 1e-9:
            differ += 1
            assert kind == "reeds_shepp"
        # our path ends at the goal whichever word it took
        np.testing.assert_allclose(ours[-1, :2], q[:2], atol=1e-9)
        assert abs((ours[-1, 2] - q[2] + math.pi) % (2 * math.pi) - math.pi) < 1e-9
    assert differ <= 20


@settings(max_examples=200, deadline=None)
@given(st.tuples(*[st.floats(-20, 20)] * 2, st.floats(-math.pi, math.pi)),
       st.tuples(*[st.floats(-20, 20)] * 2, st.floats(-math.pi, math.pi)),
       st.floats(0.2, 5.0), st.sampled_from(["reeds_shepp", "dubins"]))
def test_sampled_path_is_a_feasible_curve_from_start_to_goal(a, b, radius, kind):
    """Dense samples start at a, end at b, move at most the arc length between samples, turn at most
    1/radius per metre, and (Dubins) never reverse."""
    seg = local_paths.local_path(kind, a, b, radius)
    length = local_paths.path_length(seg, radius)
    pts = local_paths.sample_every(a, seg, radius, 0.01)
    np.testing.assert_allclose(pts[0], a, atol=1e-9)
    np.testing.assert_allclose(pts[-1, :2], b[:2], atol=1e-7 * max(1.0, length))
    step = length / (len(pts) - 1)
    chord = np.hypot(*np.diff(pts[:, :2], axis=0).T)
    assert np.all(chord <= step + 1e-9)
    assert np.all(np.abs(np.diff(pts[:, 2])) <= step / radius + 1e-9)
    if kind == "dubins":
        d = np.diff(pts[:, :2], axis=0)
        along = d[:, 0] * np.cos(pts[:-1, 2]) + d[:, 1] * np.sin(pts[:-1, 2])
        assert np.all(along >= -1e-9)
