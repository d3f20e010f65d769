"""The NumPy rotation helpers agree with pydrake.math."""
import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RollPitchYaw, RotationMatrix

from alight.systems.rotations import (heading, quaternion_from_rotation_vector,
                                      quaternion_product, rotation_between, rotation_matrix)

RNG = np.random.default_rng(0)
QUATERNIONS = [q / np.linalg.norm(q) for q in RNG.normal(size=(20, 4))]


@pytest.mark.parametrize("q", QUATERNIONS)
def test_rotation_matrix_and_product_match_drake(q):
    np.testing.assert_allclose(rotation_matrix(q), RotationMatrix(Quaternion(q)).matrix(),
                               atol=1e-12)
    p = QUATERNIONS[0]
    expected = (RotationMatrix(Quaternion(q)) @ RotationMatrix(Quaternion(p))).matrix()
    np.testing.assert_allclose(rotation_matrix(quaternion_product(q, p)), expected, atol=1e-12)


def test_rotation_between_and_rotation_vector():
    a, b = np.array([0, 0, 1.0]), np.array([1.0, 0, 0])
    np.testing.assert_allclose(rotation_matrix(rotation_between(a, b)) @ a, b, atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(rotation_between(a, -a)) @ a, -a, atol=1e-12)
    r = np.array([0.1, -0.2, 0.3])
    R = rotation_matrix(quaternion_from_rotation_vector(r))
    np.testing.assert_allclose(R, _axis_angle(r), atol=1e-12)


def _axis_angle(r):
    from pydrake.common.eigen_geometry import AngleAxis
    angle = np.linalg.norm(r)
    return RotationMatrix(AngleAxis(angle, r / angle)).matrix()


def test_heading_is_the_azimuth_of_the_projected_b1_even_at_large_tilt():
    # M(3)-(5): heading is the azimuth of b1 projected on the horizontal plane.
    R = RollPitchYaw(0.6, 0.5, 1.2).ToRotationMatrix().matrix()
    b1 = R[:, 0]
    assert heading(R) == pytest.approx(np.arctan2(b1[1], b1[0]))
    # A pure heading rotation followed by any tilt about b2 keeps the heading.
    R = (RollPitchYaw(0, 0, 0.8).ToRotationMatrix() @ RollPitchYaw(0, 0.7, 0).ToRotationMatrix())
    assert heading(R.matrix()) == pytest.approx(0.8)
