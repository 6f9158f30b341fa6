"""Structure maps: projected 2D boxes, near-plane clipping, conditioning channels, the picture."""

from __future__ import annotations

import numpy as np
import pytest

from recondreamer.scene.structure import (
    CLASS_COLOURS,
    NEAR,
    STRUCTURE_CHANNELS,
    draw_structure_map,
    line_width,
    project_box_2d,
    structure_channels,
    track_code,
    track_colour,
)
from recondreamer.scene.types import Box, Polyline
from scene_fixtures import CAM_TO_EGO, yaw_pose

WIDTH, HEIGHT = 120, 80
FX, FY, CX, CY = 100.0, 100.0, 60.0, 40.0
K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
CAMERA = CAM_TO_EGO  # at world (1, 0, 1.5), looking along world +x; camera x = -world y, camera y = -(world z - 1.5)


def box_at(
    x: float, y: float, z: float, size=(4.0, 2.0, 1.0), label: str = "vehicle", track_id: str = "car", yaw: float = 0.0
) -> Box:
    return Box(track_id, label, np.array(size, dtype=float), yaw_pose(x, y, z, yaw), num_points=20)


def channel(maps: np.ndarray, name: str) -> np.ndarray:
    return maps[STRUCTURE_CHANNELS.index(name)]


def test_hand_placed_box_projects_to_the_expected_corners():
    # Centre 20 m ahead at camera height: camera-frame corners x in {-1, 1}, y in {-0.5, 0.5}, z in {17, 21}.
    result = project_box_2d(box_at(20.0, 0.0, 1.5), K, CAMERA, WIDTH, HEIGHT)
    expected = [CX - FX / 17, CY - 0.5 * FY / 17, CX + FX / 17, CY + 0.5 * FY / 17]
    np.testing.assert_allclose(result.xyxy, expected, atol=1e-9)
    assert result.fully_inside and result.in_front
    assert (result.track_id, result.label) == ("car", "vehicle")


def test_box_partly_outside_the_image_is_not_fully_inside():
    result = project_box_2d(box_at(8.0, 3.0, 1.5), K, CAMERA, WIDTH, HEIGHT)  # 3 m left at 5-9 m
    assert result.in_front and not result.fully_inside
    assert result.xyxy[0] < 0  # leaves through the left border
    np.testing.assert_allclose(result.xyxy[0], CX + FX * (-4.0) / 5.0)


def test_box_behind_the_camera():
    result = project_box_2d(box_at(-10.0, 0.0, 1.5), K, CAMERA, WIDTH, HEIGHT)
    assert not result.in_front and not result.fully_inside
    assert np.isnan(result.xyxy).all()


def test_box_straddling_the_near_plane_is_clipped_not_flipped():
    """A box beside the camera reaching behind it: only its part in front of z = NEAR counts."""
    # World x in [-1, 3] -> camera z in [-2, 2]; world y in [2, 4] -> camera x in [-4, -2]; z in [1, 2] -> y in [-0.5, 0.5].
    result = project_box_2d(box_at(1.0, 3.0, 1.5), K, CAMERA, WIDTH, HEIGHT)
    assert result.in_front and not result.fully_inside
    expected = [CX + FX * -4.0 / NEAR, CY + FY * -0.5 / NEAR, CX + FX * -2.0 / 2.0, CY + FY * 0.5 / NEAR]
    np.testing.assert_allclose(result.xyxy, expected, rtol=1e-9)
    assert result.xyxy[2] < CX  # a naive projection of the corners behind would reach u = CX + 2 FX


def test_box_mask_matches_the_projected_box_and_carries_depth_and_track_code():
    box = box_at(20.0, 0.0, 1.5, size=(4.0, 4.0, 2.0), track_id="veh-12")
    maps = structure_channels([box], [], K, CAMERA, WIDTH, HEIGHT)
    assert maps.shape == (len(STRUCTURE_CHANNELS), HEIGHT, WIDTH) and maps.dtype == np.float32
    mask = channel(maps, "box_vehicle") > 0
    rows, cols = np.nonzero(mask)
    x0, y0, x1, y1 = project_box_2d(box, K, CAMERA, WIDTH, HEIGHT).xyxy  # about 48.2..71.8 x 34.1..45.9
    assert abs(cols.min() - x0) <= 1 and abs(cols.max() - x1) <= 1
    assert abs(rows.min() - y0) <= 1 and abs(rows.max() - y1) <= 1
    # The only visible face is the rear one, a plane at z = 17 m.
    np.testing.assert_allclose(channel(maps, "box_inverse_depth")[mask], 1.0 / 17.0, rtol=1e-6)
    np.testing.assert_allclose(channel(maps, "box_track_code")[mask], track_code("veh-12"), rtol=1e-6)
    assert not channel(maps, "box_vulnerable").any() and not channel(maps, "box_sign").any()
    assert (channel(maps, "box_track_code")[~mask] == 0).all()


def test_nearer_box_hides_the_farther_one():
    far = box_at(30.0, 0.0, 1.5, size=(4.0, 6.0, 3.0), track_id="far")
    near = box_at(12.0, 0.0, 1.5, size=(1.0, 1.0, 1.8), label="pedestrian", track_id="near")
    maps = structure_channels([near, far], [], K, CAMERA, WIDTH, HEIGHT)  # input order must not matter
    centre = (int(CY), int(CX))
    assert channel(maps, "box_vulnerable")[centre] == 1 and channel(maps, "box_vehicle")[centre] == 0
    assert channel(maps, "box_track_code")[centre] == pytest.approx(track_code("near"))
    assert channel(maps, "box_inverse_depth")[centre] == pytest.approx(1.0 / 10.5)
    edge = (int(CY), int(CX + 0.8 * FX * 3.0 / 28.0))  # inside the far box, beside the pedestrian
    assert channel(maps, "box_vehicle")[edge] == 1


def test_lines_are_clipped_at_the_near_plane_and_hidden_by_boxes():
    # A lane line 1.75 m to the left, from 50 m behind to 50 m ahead of the camera.
    line = Polyline("road_line", np.array([[-50.0, 1.75, 0.0], [0.0, 1.75, 0.0], [50.0, 1.75, 0.0]]))
    maps = structure_channels([], [line], K, CAMERA, WIDTH, HEIGHT)
    rows, cols = np.nonzero(channel(maps, "road_line"))
    assert len(cols) > 20
    # Camera-frame: x = -1.75, y = +1.5. Every visible pixel lies in the lower-left quadrant,
    # on the ray u - CX = -(1.75 / 1.5) (v - CY); projecting the behind part would flip it right/up.
    half = line_width(HEIGHT) / 2 + 1
    assert (cols <= CX + half).all() and (rows >= CY - half).all()
    np.testing.assert_allclose(cols - CX, -(1.75 / 1.5) * (rows - CY), atol=2 * half)
    assert not channel(maps, "road_edge").any() and not channel(maps, "lane_center").any()

    behind = Polyline("road_edge", np.array([[-30.0, -3.0, 0.0], [-5.0, -3.0, 0.0]]))
    assert not structure_channels([], [behind], K, CAMERA, WIDTH, HEIGHT).any()

    cover = box_at(5.0, 1.75, 0.5, size=(4.0, 3.0, 1.0))
    covered = structure_channels([cover], [line], K, CAMERA, WIDTH, HEIGHT)
    box_pixels = channel(covered, "box_vehicle") > 0
    assert box_pixels.any()
    assert not (channel(covered, "road_line") > 0)[box_pixels].any()


def test_crosswalk_goes_to_the_road_line_channel():
    crosswalk = Polyline("crosswalk", np.array([[15.0, -3.0, 0.0], [15.0, 3.0, 0.0]]))
    maps = structure_channels([], [crosswalk], K, CAMERA, WIDTH, HEIGHT)
    assert channel(maps, "road_line").any()


def test_track_codes_and_colours_are_stable_per_track():
    assert track_code("a") == track_code("a")
    assert 0.25 <= track_code("x") <= 1.0
    codes = {track_code(f"track-{i}") for i in range(50)}
    assert len(codes) > 40
    assert track_colour("vehicle", "t1") == track_colour("vehicle", "t1")
    red, green, blue = track_colour("pedestrian", "t1")
    assert red > green and red > blue  # the class colour keeps its hue


def test_draw_structure_map_colours():
    box = box_at(20.0, 0.0, 1.5, track_id="car-5")
    edge = Polyline("road_edge", np.array([[5.0, -3.0, 0.0], [60.0, -3.0, 0.0]]))
    picture = draw_structure_map([box], [edge], K, CAMERA, WIDTH, HEIGHT)
    assert picture.shape == (HEIGHT, WIDTH, 3) and picture.dtype == np.uint8
    assert tuple(picture[int(CY), int(CX)]) == track_colour("vehicle", "car-5")
    base = np.array(CLASS_COLOURS["vehicle"])
    assert np.argmax(picture[int(CY), int(CX)]) == np.argmax(base)
    assert picture[:5].max() == 0  # nothing above the horizon except boxes
    assert picture[int(CY) + 5 :, int(CX) + 5 :].any()  # the right road edge is drawn
