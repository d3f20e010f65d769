"""NED/FRD on the wire <-> DESIGN.md frames (W z up, B x forward / y left / z up): round trips,
agreement with pydrake.math, and the physical meaning of each conversion; connection strings."""
import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RollPitchYaw, RotationMatrix

from alight.hw.connection import MavlinkConnectionError, parse_connection
from alight.hw.frames import (X_HALF_TURN, b_to_frd, frd_to_b, ned_to_w, ned_yaw_to_heading,
                              q_nf_to_wb, q_wb_to_nf, w_to_ned)
from alight.systems.rotations import heading, rotation_matrix

RNG = np.random.default_rng(7)
QUATERNIONS = [q / np.linalg.norm(q) for q in RNG.normal(size=(50, 4))]
VECTORS = RNG.normal(size=(50, 3)) * 10


def test_half_turn_is_drakes_x_rotation():
    np.testing.assert_allclose(X_HALF_TURN, RotationMatrix.MakeXRotation(np.pi).matrix(),
                               atol=1e-15)


@pytest.mark.parametrize("q_WB", QUATERNIONS[:10])
def test_quaternion_round_trip_and_drake_agreement(q_WB):
    q_NF = q_wb_to_nf(q_WB)
    np.testing.assert_allclose(q_nf_to_wb(q_NF), q_WB, atol=1e-15)
    # R_NF = R_NW R_WB R_BF with R_NW = R_BF = R_x(pi), computed by Drake.
    X = RotationMatrix.MakeXRotation(np.pi)
    R_NF = X @ RotationMatrix(Quaternion(q_WB)) @ X
    np.testing.assert_allclose(RotationMatrix(Quaternion(q_NF)).matrix(), R_NF.matrix(),
                               atol=1e-12)
    assert abs(np.linalg.norm(q_NF) - 1.0) < 1e-12


def test_all_quaternions_and_vectors_round_trip():
    for q in QUATERNIONS:
        np.testing.assert_allclose(q_wb_to_nf(q_nf_to_wb(q)), q, atol=1e-15)
    for v in VECTORS:
        np.testing.assert_array_equal(w_to_ned(ned_to_w(v)), v)
        np.testing.assert_array_equal(b_to_frd(frd_to_b(v)), v)


def test_a_vector_rotated_on_the_wire_is_the_same_vector_rotated_on_the_ports():
    for q_NF, v_F in zip(QUATERNIONS, VECTORS):
        v_N = RotationMatrix(Quaternion(q_NF)).multiply(v_F)
        v_W = rotation_matrix(q_nf_to_wb(q_NF)) @ frd_to_b(v_F)
        np.testing.assert_allclose(v_W, ned_to_w(v_N), atol=1e-9)


def test_physical_meaning():
    # Up is -z in NED and +z in W; gravity's specific force at rest reads -g in FRD, +g in B.
    np.testing.assert_array_equal(ned_to_w([0, 0, -1.0]), [0, 0, 1.0])
    np.testing.assert_array_equal(frd_to_b([0, 0, -9.81]), [0, 0, 9.81])
    # A right-wing-down roll rate (+x FRD) is the same +x rate in B; a nose-right yaw rate
    # (+z FRD, clockwise from above) is a negative (clockwise) rate about z up.
    np.testing.assert_array_equal(frd_to_b([0.3, 0, 0.2]), [0.3, 0, -0.2])
    # Level, facing east in NED (yaw +90 deg) is heading -90 deg in W (x_W north, y_W west).
    q_NF = RollPitchYaw(0, 0, np.pi / 2).ToQuaternion().wxyz()
    eta = heading(rotation_matrix(q_nf_to_wb(q_NF)))
    assert eta == pytest.approx(-np.pi / 2) == pytest.approx(ned_yaw_to_heading(np.pi / 2))
    # A 10 deg right-wing-down roll in FRD is a 10 deg roll about x_B with y_B (left) going up.
    q_NF = RollPitchYaw(np.radians(10), 0, 0).ToQuaternion().wxyz()
    R_WB = rotation_matrix(q_nf_to_wb(q_NF))
    assert R_WB[2, 1] == pytest.approx(np.sin(np.radians(10)))  # z_W component of y_B


@pytest.mark.parametrize("url, role, device, options", [
    ("udp:127.0.0.1:14540", "connect", "udpout:127.0.0.1:14540", {}),
    ("udp:127.0.0.1:14540", "listen", "udpin:127.0.0.1:14540", {}),
    ("udpin:0.0.0.0:14540", "connect", "udpin:0.0.0.0:14540", {}),
    ("tcp:localhost:5760", "connect", "tcp:localhost:5760", {}),
    ("serial:/dev/ttyACM0:921600", "connect", "/dev/ttyACM0", {"baud": 921600}),
])
def test_connection_strings(url, role, device, options):
    assert parse_connection(url, role) == (device, options)


@pytest.mark.parametrize("url", ["udp:14540", "udp:host:99999", "serial:/dev/ttyACM0",
                                 "serial:/dev/ttyACM0:fast", "zigbee:1:2", "udp:host:port"])
def test_bad_connection_strings_are_refused_with_the_forms(url):
    with pytest.raises(MavlinkConnectionError, match=url.split(":")[0]):
        parse_connection(url, "connect")
