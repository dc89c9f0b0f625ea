"""Pose algebra (Eqs. 1–6): identities that any correct implementation satisfies."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmslam.runtime.pose import (
    between,
    between_nb,
    compose,
    compose_nb,
    from_matrix,
    interpolate,
    inverse,
    to_matrix,
    transform_point_nb,
    transform_points,
    wrap_angle,
    wrap_angle_nb,
)

coord = st.floats(-50, 50, allow_nan=False)
angle = st.floats(-20, 20, allow_nan=False)
poses = st.tuples(coord, coord, angle).map(lambda p: np.array(p))


def close(a, b, tol=1e-9):
    a, b = np.asarray(a), np.asarray(b)
    assert np.allclose(a[..., :2], b[..., :2], atol=tol)
    assert np.allclose(wrap_angle(a[..., 2] - b[..., 2]), 0.0, atol=tol)


@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_wrap_angle_range_and_equivalence(a):
    w = float(wrap_angle(a))
    assert -math.pi <= w < math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)
    assert wrap_angle_nb(a) == w


def test_wrap_angle_half_open_interval():
    assert wrap_angle(math.pi) == -math.pi
    assert wrap_angle(-math.pi) == -math.pi
    assert wrap_angle_nb(3 * math.pi) == -math.pi


@given(poses, poses)
def test_between_undoes_compose(a, d):
    close(between(compose(a, d), a), d, 1e-7)


@given(poses, poses)
def test_compose_undoes_between(a, b):
    close(compose(b, between(a, b)), a, 1e-7)


@given(poses)
def test_inverse_is_involution_and_cancels(d):
    close(inverse(inverse(d)), d, 1e-7)
    close(compose(d, inverse(d)), np.zeros(3), 1e-7)


@given(poses, poses, poses)
@settings(max_examples=50)
def test_compose_is_associative(a, b, c):
    close(compose(compose(a, b), c), compose(a, compose(b, c)), 1e-6)


@given(poses, poses)
def test_matrix_composition_matches_eq1(a, b):
    close(from_matrix(to_matrix(a) @ to_matrix(b)), compose(a, b), 1e-7)


@given(poses, st.tuples(coord, coord))
def test_transform_point_matches_matrix(p, pt):
    hom = to_matrix(p) @ np.array([pt[0], pt[1], 1.0])
    assert np.allclose(transform_points(p, np.array([pt])), hom[:2][None], atol=1e-8)
    assert np.allclose(transform_point_nb(p[0], p[1], p[2], pt[0], pt[1]), hom[:2], atol=1e-8)


@given(poses, poses)
def test_numba_kernels_equal_numpy(a, b):
    assert np.allclose(compose_nb(*a, *b), compose(a, b), atol=1e-9)
    assert np.allclose(between_nb(*a, *b), between(a, b), atol=1e-9)


@given(poses, poses)
def test_interpolate_runs_from_one_pose_to_the_other_the_short_way(a, b):
    close(interpolate(a, b, 0.0), a)
    close(interpolate(a, b, 1.0), b)
    half = interpolate(a, b, 0.5)
    assert np.allclose(half[:2], (a[:2] + b[:2]) / 2)
    turn = wrap_angle(b[2] - a[2])  # the shorter arc, whichever way round the angles were given
    assert abs(wrap_angle(half[2] - a[2])) <= abs(turn) / 2 + 1e-9
    assert abs(wrap_angle(interpolate(a, b, 0.25)[2] - a[2] - turn / 4)) < 1e-9


def test_interpolate_crosses_pi_not_zero():
    mid = interpolate([0, 0, 3.0], [2, 0, -3.0], 0.5)
    assert np.allclose(mid[:2], [1, 0]) and abs(abs(mid[2]) - math.pi) < 1e-12


def test_vectorised_over_leading_axes():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(4, 5, 3))
    b = rng.normal(size=(4, 5, 3))
    out = compose(a, b)
    assert out.shape == (4, 5, 3)
    close(out[2, 3], compose(a[2, 3], b[2, 3]))


def test_bad_pose_shape_is_named():
    import pytest

    with pytest.raises(ValueError, match="3 components"):
        compose(np.zeros(2), np.zeros(3))
