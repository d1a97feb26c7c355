"""Joining the pieces of one vehicle along its track's predicted box."""

from __future__ import annotations

import numpy as np

from core.config import TrackingConfig
from core.packets import BOX, NETWORK, Detection, Measurement
from stages.tracking import ObjectTracker
from stages.vehicle_fragments import join_fragments


def _piece(x: int, w: int, height_m: float, blob: int | None = 1, y: int = 100, h: int = 28) -> Detection:
    return Detection(box=(float(x), float(y), float(w), float(h)),
                     heights={NETWORK: Measurement(height_m, 0.3, "test"), BOX: Measurement(2.0, 0.1, "test")},
                     cls="vehicle", cls_source="objects", mask=np.ones((h, w), bool), blob=blob)


BUS = (50.0, 100.0, 90.0, 28.0)         # the vehicle track's predicted box


def test_the_pieces_of_a_vehicle_side_by_side_become_one_detection():
    rear, middle, front = _piece(50, 40, 1.9), _piece(75, 30, 1.2), _piece(90, 50, 3.6)   # overlapping boxes
    walker = Detection(box=(200.0, 90.0, 10.0, 30.0), cls="person", mask=np.ones((30, 10), bool), blob=2)
    joined = join_fragments([rear, walker, middle, front], [BUS, walker.box], ["vehicle", "person"])
    assert len(joined) == 2 and joined[1] is walker
    bus = joined[0]
    assert bus.box == (50.0, 100.0, 90.0, 28.0) and bus.mask.shape == (28, 90) and bus.mask.all()
    # The blob's top is its highest piece's; the geometry read a piece's outline, not the bus's.
    assert bus.heights == {NETWORK: front.heights[NETWORK]}
    assert (bus.cls, bus.cls_source) == ("vehicle", "tracking")


def test_two_vehicles_stay_two():
    rear, front = _piece(50, 45, 1.9), _piece(95, 45, 3.6)
    # Another track's prediction explains the front piece better: two vehicles side by side.
    assert join_fragments([rear, front], [BUS, front.box], ["vehicle", "vehicle"]) == [rear, front]
    # Pieces of different blobs: the foreground parted them.
    other = _piece(95, 45, 3.6, blob=2)
    assert join_fragments([rear, other], [BUS], ["vehicle"]) == [rear, other]
    # A piece reaching well outside the prediction (a car passing behind the bus) fits it worse.
    beyond = _piece(95, 80, 1.5)
    assert join_fragments([rear, beyond], [BUS], ["vehicle"]) == [rear, beyond]
    # One above the other is not side by side (a vehicle's pieces stand on one road).
    low, high = _piece(50, 90, 1.9, y=114, h=14), _piece(50, 90, 3.6, y=100, h=14)
    assert join_fragments([low, high], [BUS], ["vehicle"]) == [low, high]


def test_a_walkers_prediction_gathers_nothing_nor_does_a_network_box():
    rear, front = _piece(50, 45, 1.9), _piece(95, 45, 3.6)
    assert join_fragments([rear, front], [BUS], ["person"]) == [rear, front]
    network = Detection(box=front.box, cls="vehicle", cls_source="network", mask=front.mask)
    assert join_fragments([rear, network], [BUS], ["vehicle"]) == [rear, network]


def test_a_bus_cut_into_pieces_keeps_one_track():
    """A bus seen whole, then cut into two to three pieces frame after frame: one track, no new one."""
    tracker = ObjectTracker(TrackingConfig(min_hits=2))
    x = 40
    for frame in range(12):
        x += 4
        if frame < 4:
            detections = [_piece(x, 90, 3.4, blob=1)]
        elif frame % 2:
            detections = [_piece(x, 50, 1.9), _piece(x + 48, 42, 3.6)]
        else:
            detections = [_piece(x, 30, 1.3), _piece(x + 25, 35, 1.9), _piece(x + 55, 35, 3.7)]
        tracks = tracker.update(detections)
    assert [t.track_id for t in tracks] == [1]
    assert abs(tracks[0].box[0] - x) <= 2 and abs(tracks[0].box[2] - 90) <= 4
