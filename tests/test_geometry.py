import numpy as np
import pytest

from polycam.geometry import (R_from_quat, R_from_r, T_from_rt, T_inverse, quat_from_R, r_from_R,
                              rt_from_T, skew, transform_points)
from polycam.lightfield import FACE_NAMES, R_rig_face_for
from tolerances import GEOMETRY_ATOL


def random_r(rng, n):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(0, np.pi * 0.999, size=(n, 1))


def test_rotation_round_trips(rng):
    r = random_r(rng, 200)
    R = R_from_r(r)
    assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=GEOMETRY_ATOL)
    assert np.allclose(np.linalg.det(R), 1.0, atol=GEOMETRY_ATOL)
    assert np.allclose(r_from_R(R), r, atol=1e-8)
    assert np.allclose(R_from_quat(quat_from_R(R)), R, atol=GEOMETRY_ATOL)
    assert np.all(quat_from_R(R)[:, 3] >= 0)


def test_small_and_half_turn_angles():
    for r in ([0, 0, 0], [1e-12, 0, 0], [np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi]):
        R = R_from_r(np.array(r, float))
        assert np.allclose(R_from_r(r_from_R(R)), R, atol=1e-7)


def test_rodrigues_matches_skew_exponential():
    w = np.array([0.3, -0.2, 0.5])
    K = skew(w)
    # exp(K) by a long Taylor series
    E, term = np.eye(3), np.eye(3)
    for k in range(1, 30):
        term = term @ K / k
        E = E + term
    assert np.allclose(R_from_r(w), E, atol=1e-12)
    assert np.allclose(K @ np.array([1.0, 2.0, 3.0]), np.cross(w, [1.0, 2.0, 3.0]))


def test_transform_inverse_and_rt(rng):
    rt = np.concatenate([random_r(rng, 10), rng.normal(size=(10, 3))], axis=1)
    T = T_from_rt(rt)
    assert np.allclose(T @ T_inverse(T), np.eye(4), atol=GEOMETRY_ATOL)
    assert np.allclose(rt_from_T(T), rt, atol=1e-8)
    p = rng.normal(size=(5, 3))
    assert np.allclose(transform_points(T_inverse(T[0]), transform_points(T[0], p)), p, atol=1e-12)


@pytest.mark.parametrize("name", FACE_NAMES)
def test_cube_faces_are_rotations_looking_along_their_name(name):
    R = R_rig_face_for(name)
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    axis = {"x": 0, "y": 1, "z": 2}[name[1]]
    expected = np.zeros(3)
    expected[axis] = 1.0 if name[0] == "+" else -1.0
    assert np.allclose(R[:, 2], expected)


def test_cube_faces_cover_all_directions():
    zs = np.stack([R_rig_face_for(n)[:, 2] for n in FACE_NAMES])
    assert np.allclose(np.abs(zs).sum(axis=0), 2.0)


def test_adjoint_maps_twists_between_frames(rng):
    """adjoint(T) carries a small motion's twist (v, ω) from frame b into frame a:
    T exp(ξ) T⁻¹ = exp(Ad_T ξ) to first order."""
    from polycam.geometry import R_from_r, T_from_Rt, T_inverse, adjoint

    T = T_from_Rt(R_from_r(rng.normal(size=3)), rng.normal(size=3))
    xi = 1e-6 * rng.normal(size=6)
    small = T_from_Rt(R_from_r(xi[3:]), xi[:3])
    moved = T @ small @ T_inverse(T)
    got = np.concatenate([moved[:3, 3], r_from_R(moved[:3, :3])])
    np.testing.assert_allclose(got, adjoint(T) @ xi, atol=GEOMETRY_ATOL)
