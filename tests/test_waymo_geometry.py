"""Waymo geometry helpers against independent constructions."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from recondreamer.sources.waymo import geometry, schema


def _elementary(axis: int, angle: float) -> np.ndarray:  # (3,3) right-handed rotation about one axis
    c, s = np.cos(angle), np.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3  # cyclic order keeps it right-handed (y: z then x)
    rotation = np.eye(3)
    rotation[i, i], rotation[i, j], rotation[j, i], rotation[j, j] = c, -s, s, c
    return rotation


def test_euler_is_yaw_then_pitch_then_roll():
    rng = np.random.default_rng(0)
    roll, pitch, yaw = rng.uniform(-np.pi, np.pi, (3, 5))
    rotations = geometry.euler_to_rotation(roll, pitch, yaw)
    for k in range(5):
        expected = _elementary(2, yaw[k]) @ _elementary(1, pitch[k]) @ _elementary(0, roll[k])
        np.testing.assert_allclose(rotations[k], expected, atol=1e-12)


def test_opencv_axes():
    # OpenCV x (right) is Waymo -y (left), y (down) is -z (up), z (optical axis) is x (forward).
    np.testing.assert_array_equal(geometry.WAYMO_FROM_OPENCV @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_array_equal(geometry.WAYMO_FROM_OPENCV @ [0, 1, 0], [0, 0, -1])
    np.testing.assert_array_equal(geometry.WAYMO_FROM_OPENCV @ [0, 0, 1], [1, 0, 0])
    assert np.linalg.det(geometry.WAYMO_FROM_OPENCV) == pytest.approx(1.0)


def test_rigid_inverse():
    pose = np.eye(4)
    pose[:3, :3] = geometry.euler_to_rotation(np.array(0.1), np.array(-0.2), np.array(2.0))
    pose[:3, 3] = [1000.0, -20.0, 3.0]
    np.testing.assert_allclose(geometry.rigid_inverse(pose) @ pose, np.eye(4), atol=1e-12)


def test_uniform_beam_inclinations_when_none_are_listed():
    calibration = schema.LaserCalibration(beam_inclination_min=-0.4, beam_inclination_max=0.0)
    rows = geometry.beam_inclinations(calibration, 4)
    np.testing.assert_allclose(rows, [-0.05, -0.15, -0.25, -0.35])  # row centres, highest first
    calibration.beam_inclinations[:] = [-0.3, -0.1, 0.0]
    np.testing.assert_allclose(geometry.beam_inclinations(calibration, 3), [0.0, -0.1, -0.3])
    with pytest.raises(ValueError, match="3 beam inclinations for a 4-row range image"):
        geometry.beam_inclinations(calibration, 4)


def test_decode_matrix_float():
    values = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    matrix = schema.MatrixFloat()
    matrix.data[:] = values.reshape(-1).tolist()
    matrix.shape.dims[:] = [2, 3, 4]
    np.testing.assert_array_equal(geometry.decode_matrix_float(zlib.compress(matrix.SerializeToString())), values)
    matrix.shape.dims[:] = [5, 5]
    with pytest.raises(ValueError, match=r"holds 24 values but its shape is \(5, 5\)"):
        geometry.decode_matrix_float(zlib.compress(matrix.SerializeToString()))


def test_unknown_enum_values_are_kept():
    """Enums are int32 in the own schema: a label type this code does not know survives parsing."""
    label = schema.Label(type=17, id="x")
    assert schema.Label.FromString(label.SerializeToString()).type == 17


def test_box_pose_heading():
    box = schema.Label().box
    box.center_x, box.center_y, box.center_z, box.heading = 1.0, 2.0, 3.0, np.pi / 2
    pose = geometry.box_to_vehicle(box)
    np.testing.assert_allclose(pose[:3, 0], [0.0, 1.0, 0.0], atol=1e-15)  # length axis points along +y
    np.testing.assert_allclose(pose[:3, 3], [1.0, 2.0, 3.0])
