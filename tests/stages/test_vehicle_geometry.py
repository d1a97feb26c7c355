"""Vehicle geometry: the height of a box on the ground from its outline alone."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.config import CameraConfig
from core.packets import BOX, Detection, Frame, FramePacket
from stages.calibration import camera_from_pose, heights_from_foot_top, intrinsics_from_fov, project_points
from stages.geometry import GeometryMeasurer
from stages.vehicle_geometry import vehicle_box

CAMERA = camera_from_pose(1280, 720, intrinsics_from_fov(1280, 720, 60), 6.4, 20.0)


def box_outline(camera, centre, yaw_deg, length, width, height, cabin=None, clearance=0.3):
    """Outline (mask, origin) of a vehicle: a body box ``clearance`` above the road on four wheels.

    Each part's 8 corners are projected and their hull filled. ``cabin`` = (length, width, lower
    z): a car's cabin on top of a body that ends at the lower z.
    """
    yaw = np.deg2rad(yaw_deg)
    along, across = np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])
    body_top = height if cabin is None else cabin[2]
    parts = [((0.0, 0.0), length, width, clearance, body_top)]
    if cabin is not None:
        parts.append(((0.0, 0.0), cabin[0], cabin[1], cabin[2], height))
    parts += [((a * (length / 2 - 0.8), b * (width / 2 - 0.15)), 0.6, 0.25, 0.0, clearance + 0.05)
              for a in (-1, 1) for b in (-1, 1)]
    image = np.zeros((camera.height, camera.width), np.uint8)
    for (offset_along, offset_across), part_length, part_width, bottom, top in parts:
        middle = np.asarray(centre) + offset_along * along + offset_across * across
        footprint = [middle + a * part_length / 2 * along + b * part_width / 2 * across
                     for a, b in ((1, 1), (1, -1), (-1, -1), (-1, 1))]
        uv = project_points(camera, np.array([[*p, z] for z in (bottom, top) for p in footprint]))
        cv2.fillConvexPoly(image, np.round(cv2.convexHull(uv.astype(np.float32)) * 16).astype(np.int32), 1,
                           lineType=cv2.LINE_8, shift=4)
    rows, cols = np.nonzero(image)
    x0, y0 = cols.min(), rows.min()
    return image[y0:rows.max() + 1, x0:cols.max() + 1].astype(bool), (float(x0), float(y0))


# Seen from the side the lower outline runs under the wheels, below the plane its points are put
# on (body_clearance_m): the footprint comes out nearer and the height ~0.15 m high.
SIDE_VIEW_TOLERANCE_M = 0.2
OBLIQUE_TOLERANCE_M = 0.1


@pytest.mark.parametrize("yaw, tolerance", [(0.0, SIDE_VIEW_TOLERANCE_M), (30.0, OBLIQUE_TOLERANCE_M),
                                            (60.0, OBLIQUE_TOLERANCE_M), (120.0, OBLIQUE_TOLERANCE_M)])
def test_a_box_vans_height_comes_back_from_its_outline(yaw, tolerance):
    mask, origin = box_outline(CAMERA, (2.0, 18.0), yaw, 5.2, 2.0, 2.2)
    fitted = vehicle_box(CAMERA, mask, origin)
    assert fitted is not None
    assert fitted.height_m == pytest.approx(2.2, abs=tolerance)


def test_the_foot_top_geometry_reads_the_same_outline_far_too_high():
    """Why the box exists: the outline's top is the far roof edge, metres behind its lowest point."""
    mask, (x0, y0) = box_outline(CAMERA, (2.0, 18.0), 30.0, 5.2, 2.0, 2.2)
    rows, cols = np.nonzero(mask)
    centre_col = x0 + (cols.min() + cols.max() + 1) / 2
    foot_top, _ = heights_from_foot_top(CAMERA, np.array([[centre_col, y0 + rows.max() + 1]]),
                                        np.array([[centre_col, y0 + rows.min()]]))
    assert foot_top[0] > 2.2 + 0.5
    assert abs(vehicle_box(CAMERA, mask, (x0, y0)).height_m - 2.2) < OBLIQUE_TOLERANCE_M


@pytest.mark.parametrize("yaw, tolerance", [(0.0, SIDE_VIEW_TOLERANCE_M), (40.0, OBLIQUE_TOLERANCE_M),
                                            (70.0, OBLIQUE_TOLERANCE_M)])
def test_a_cars_cabin_is_its_roof(yaw, tolerance):
    # Body to 0.9 m, cabin half as long and 0.2 m narrower on top, to 1.5 m.
    mask, origin = box_outline(CAMERA, (1.0, 16.0), yaw, 4.4, 1.8, 1.5, cabin=(2.3, 1.6, 0.9))
    fitted = vehicle_box(CAMERA, mask, origin)
    assert fitted is not None
    assert fitted.height_m == pytest.approx(1.5, abs=tolerance)


def test_a_car_seen_end_on_gets_a_cars_length_along_the_line_of_sight():
    mask, origin = box_outline(CAMERA, (0.0, 16.0), 90.0, 4.4, 1.8, 1.5, cabin=(2.3, 1.6, 0.9))
    fitted = vehicle_box(CAMERA, mask, origin)
    assert fitted.length_assumed
    assert abs(fitted.axis_xy[1]) == pytest.approx(1.0, abs=0.01)     # the camera looks along +y
    assert fitted.height_m == pytest.approx(1.5, abs=OBLIQUE_TOLERANCE_M)


def test_a_bicycle_from_the_side_looks_like_a_cars_end_but_lies_across_its_way():
    """Only the tracker can tell them apart: the box's length axis is across the bicycle's motion."""
    mask, origin = box_outline(CAMERA, (0.0, 16.0), 0.0, 1.8, 0.5, 1.7, clearance=0.0)
    fitted = vehicle_box(CAMERA, mask, origin)
    assert fitted.length_assumed and abs(fitted.axis_xy[0]) < 0.1        # it rides along x
    end_on, _ = box_outline(CAMERA, (0.0, 16.0), 90.0, 1.8, 0.5, 1.7, clearance=0.0)
    assert vehicle_box(CAMERA, end_on, _) is None                        # narrower than any vehicle


def test_a_side_seen_edge_on_gets_a_vehicles_width_behind_it():
    # Camera looking straight down the side of a bus: the footprint seen is a line.
    mask, origin = box_outline(CAMERA, (0.0, 15.0), 0.0, 11.0, 2.5, 3.2)
    fitted = vehicle_box(CAMERA, mask, origin)
    assert fitted is not None
    assert fitted.width_m >= 1.6
    assert fitted.height_m == pytest.approx(3.2, abs=0.25)


def test_too_small_an_outline_gives_nothing():
    assert vehicle_box(CAMERA, np.ones((3, 2), bool), (600.0, 500.0)) is None
    assert vehicle_box(CAMERA, np.zeros((10, 10), bool), (600.0, 500.0)) is None


def test_the_geometry_stage_adds_a_box_reading_to_wide_whole_objects_only():
    mask, origin = box_outline(CAMERA, (2.0, 18.0), 30.0, 4.4, 1.8, 1.5, cabin=(2.3, 1.6, 0.9))
    h, w = mask.shape
    car = Detection(box=(*origin, float(w), float(h)), foot_xy=(origin[0] + w / 2, origin[1] + h),
                    top_xy=(origin[0] + w / 2, origin[1]), mask=mask, outline=mask)
    cut = Detection(box=(*origin, float(w), float(h)), foot_xy=(origin[0] + w / 2, origin[1] + h),
                    top_xy=(origin[0] + w / 2, origin[1]), mask=mask, outline=mask, touches_border=True)
    person_mask = np.ones((60, 12), bool)
    person = Detection(box=(640.0, 300.0, 12.0, 60.0), foot_xy=(646.0, 360.0), top_xy=(646.0, 300.0),
                       mask=person_mask, outline=person_mask)
    image = np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8)
    GeometryMeasurer(CameraConfig()).process(FramePacket(frame=Frame(0, 0.0, image), camera=CAMERA,
                                                         detections=[car, cut, person]))
    box = car.heights[BOX]
    assert box.value_m == pytest.approx(1.5, abs=OBLIQUE_TOLERANCE_M) and box.source == "vehicle geometry"
    assert box.noise_m > box.bias_m > 0
    assert BOX not in cut.heights and BOX not in person.heights
