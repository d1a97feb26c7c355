"""Objects from the network's detection head (``objects.source = "network"``), with fake network
detections on drawn scenes: thresholds per class, motion as a cue, heights from the box's pixels."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from media import make_tiny_contact_model
from core.config import CameraConfig, GroundConfig, ObjectsConfig
from core.errors import ConfigError, ModelError
from core.packets import NETWORK, CameraInfo, Detection, Frame, FramePacket, NetworkDetections
from stages.calibration import camera_for_run, camera_from_pose, intrinsics_from_fov
from stages.centre_detections import CentreDetections, in_frame
from stages.geometry import GeometryMeasurer
from stages.height_inference import HeightEstimator
from stages.heightnet_model import HeightNetModel
from stages.merged_blobs import split_by_predictions
from stages.network_objects import (check_classes, class_thresholds, min_score, motion_blob_floor, motion_ends,
                                    network_objects)
from stages.object_extraction import ObjectExtractor

WIDTH, HEIGHT = 320, 240
NETWORK_MODE = ObjectsConfig(source="network", score_person=0.5, score_cyclist=0.6, score_vehicle=0.7,
                             score_motion=0.2)
STANDER = (40, 60, 20, 60, 1.70)
"""x, y, w, h, height_m: a person standing still from the first frame on (in the primed background)."""


def walker(frame: int, tall: int = 50) -> tuple[int, int, int, int, float]:
    """A person walking right, under a quarter of the frame tall unless ``tall`` says otherwise."""
    return (150 + 5 * frame, 80, 20, tall, 1.80)


def _background() -> np.ndarray:
    small = np.random.default_rng(0).integers(60, 120, (HEIGHT // 8, WIDTH // 8, 3), dtype=np.uint8)
    return np.kron(small, np.ones((8, 8, 1), dtype=np.uint8))


def scene(people: list[tuple[int, int, int, int, float]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image, height map (each person from height_m at the crown to 0.05 m at the soles), ground."""
    image = _background().copy()
    heights = np.zeros((HEIGHT, WIDTH), np.float32)
    for x, y, w, h, height_m in people:
        texture = np.random.default_rng(int(height_m * 100)).integers(0, 255, (h // 4 + 1, w // 4 + 1, 3))
        image[y:y + h, x:x + w] = np.kron(texture, np.ones((4, 4, 1)))[:h, :w].astype(np.uint8)
        heights[y:y + h, x:x + w] = np.linspace(height_m, 0.05, h, dtype=np.float32)[:, None]
    return image, heights, heights < 0.1


def found(*boxes: tuple[str, float, tuple[float, float, float, float]]) -> NetworkDetections:
    """Network detections from (class, score, (x0, y0, x1, y1) in frame pixels)."""
    return NetworkDetections(np.array([b for _, _, b in boxes], np.float32).reshape(-1, 4),
                             tuple(cls for cls, _, _ in boxes), np.array([s for _, s, _ in boxes], np.float32))


def box_of(person: tuple[int, int, int, int, float]) -> tuple[float, float, float, float]:
    x, y, w, h, _ = person
    return (float(x), float(y), float(x + w), float(y + h))


def run(config: ObjectsConfig, last: NetworkDetections | None, frames: int = 8,
        with_walker: bool = True, walker_tall: int = 50) -> FramePacket:
    """The stander and (optionally) a walker; the background primed as a run primes it (the median
    of early frames holds the stander); ``last`` are the network's detections of the last frame."""
    extractor = ObjectExtractor(config, GroundConfig())
    people = [[STANDER] + ([walker(i, walker_tall)] if with_walker else []) for i in range(frames)]
    # Priming frames seconds apart: the walker anywhere along the way, the stander always there.
    extractor.prime_background([scene([STANDER, (80 + 20 * k, 80, 20, walker_tall, 1.8)])[0] for k in range(10)])
    for index, present in enumerate(people):
        image, heights, ground = scene(present)
        packet = FramePacket(Frame(index, index / 10, image), CameraInfo(WIDTH, HEIGHT), ground_mask=ground,
                             height_map=heights, network_detections=last if index == frames - 1 else None)
        packet = extractor.process(packet)
    return packet


# ------------------------------------------------------------------ boxes back in frame pixels

@pytest.mark.parametrize("input_size, frame_size, box, expected", [
    ((320, 240), (320, 240), (10, 20, 30, 60), (10, 20, 30, 60)),           # no resize
    ((320, 240), (640, 480), (10, 20, 30, 60), (20, 40, 60, 120)),          # same aspect, x2
    ((320, 240), (640, 360), (10, 20, 30, 60), (20, 30, 60, 90)),           # 16:9 squashed to 4:3
    ((320, 192), (1920, 1080), (0, 0, 320, 192), (0, 0, 1920, 1080)),       # the whole input: the whole frame
    ((64, 48), (160, 72), (27, 12, 35, 28), (67.5, 18, 87.5, 42)),
])
def test_boxes_map_back_to_frame_pixels_through_the_squash(input_size, frame_size, box, expected):
    decoded = CentreDetections(np.array([box], np.float32), np.array([1]), np.array([0.7], np.float32))
    mapped = in_frame(decoded, ("person", "cyclist", "vehicle"), input_size, frame_size)
    assert mapped.boxes.tolist() == [pytest.approx(expected)]
    assert mapped.classes == ("cyclist",) and mapped.scores.tolist() == [pytest.approx(0.7)]


def tiny_detector(tmp_path, classes=("person", "cyclist", "vehicle")):
    """A 64 x 48 v2 model whose head finds one person: a peak at cell (row 5, col 7), box (27, 12, 35, 28)."""
    centre = np.full((len(classes), 12, 16), -10.0, np.float32)
    centre[0, 5, 7] = 3.0
    box = np.zeros((4, 12, 16), np.float32)
    box[:, 5, 7] = (1.0, -2.0, 8.0, 16.0)        # centre (31, 20) in input pixels, 8 x 16
    return make_tiny_contact_model(tmp_path / "det.onnx", np.zeros((48, 64, 2), np.float32), np.zeros(6),
                                   detection=(list(classes), centre, box))


def test_a_model_with_a_detection_head_hands_its_boxes_on_in_frame_pixels(tmp_path):
    model = HeightNetModel(tiny_detector(tmp_path), detection_min_score=0.5)
    assert model.info.detection and model.info.detection_classes == ("person", "cyclist", "vehicle")
    assert model.info.detection_stride == 4
    camera = camera_for_run(CameraConfig(height_m=5.0), 160, 72)
    packet = FramePacket(Frame(0, 0.0, np.zeros((72, 160, 3), np.uint8)), camera)
    packet = HeightEstimator(model, camera).process(packet)
    detections = packet.network_detections
    assert detections.classes == ("person",)
    assert detections.boxes.tolist() == [pytest.approx((67.5, 18.0, 87.5, 42.0))]   # x 2.5, y 1.5
    assert detections.scores.tolist() == [pytest.approx(1 / (1 + np.exp(-3.0)))]


def test_models_without_a_declared_head_give_no_network_detections(tmp_path):
    # Outputs named like a detector's but not declared in the metadata are left alone, as before.
    model = HeightNetModel(make_tiny_contact_model(tmp_path / "v2.onnx", np.zeros((48, 64, 2)), np.zeros(6)))
    assert not model.info.detection
    assert model.infer(Frame(0, 0.0, np.zeros((48, 64, 3), np.uint8))).detections is None


def test_a_declared_head_of_the_wrong_shape_is_a_model_error(tmp_path):
    centre = np.zeros((3, 6, 8), np.float32)            # stride 8 declared, but box at another size
    path = make_tiny_contact_model(tmp_path / "bad.onnx", np.zeros((48, 64, 2)), np.zeros(6),
                                   detection=(["person", "cyclist", "vehicle"], centre, np.zeros((4, 12, 16))))
    with pytest.raises(ModelError, match="output 'box'"):
        HeightNetModel(path)


# ------------------------------------------------------------------ which boxes are objects

@pytest.mark.parametrize("who, cls, score, kept", [
    ("stander", "person", 0.55, "object"),  # confident and still: found (blobs never find it)
    ("stander", "person", 0.30, "weak"),    # weak and still: only to carry on a track
    ("walker", "person", 0.30, "object"),   # weak but moving: kept
    ("walker", "person", 0.15, "weak"),     # under score_motion, over continue_score: moving or not
    ("walker", "person", 0.05, None),       # under continue_score: dropped
    ("stander", "cyclist", 0.55, "weak"),   # each class has its own threshold
    ("stander", "cyclist", 0.65, "object"),
    ("stander", "vehicle", 0.65, "weak"),
    ("stander", "vehicle", 0.75, "object"),
    ("walker", "vehicle", 0.30, "object"),  # the motion floor is shared
])
def test_thresholds_per_class_and_motion_as_a_cue(who, cls, score, kept):
    person = STANDER if who == "stander" else walker(7)
    config = dataclasses.replace(NETWORK_MODE, score_motion=0.2, continue_score=0.1)
    packet = run(config, found((cls, score, box_of(person))))
    if kept is None:
        assert packet.detections == []
        return
    (detection,) = packet.detections
    assert detection.box == pytest.approx((person[0], person[1], person[2], person[3]))
    assert (detection.cls, detection.cls_source, detection.score) == (cls, "network", pytest.approx(score))
    assert detection.continues_only == (kept == "weak")


def _frames_of_the_stander(config: ObjectsConfig, boxes: list[NetworkDetections]) -> list[list[Detection]]:
    """The stander alone (in the primed background: it never moves), ten frames a second; frame i's
    network detections are ``boxes[i]``. Each frame's detections."""
    extractor = ObjectExtractor(config, GroundConfig())
    extractor.prime_background([scene([STANDER])[0]] * 3)
    image, heights, ground = scene([STANDER])
    return [extractor.process(FramePacket(Frame(index, index / 10, image), CameraInfo(WIDTH, HEIGHT),
                                          ground_mask=ground, height_map=heights,
                                          network_detections=found_here)).detections
            for index, found_here in enumerate(boxes)]


@pytest.mark.parametrize("still_s, score, gap_at, class_before, first_object", [
    (0.5, 0.4, None, "person", 5),      # the same box in every frame of the last 0.5 s: from the sixth frame on
    (0.0, 0.4, None, "person", None),   # off: a weak box is an object only while it moves
    (0.5, 0.4, 3, "person", 9),         # a frame without it: the half second starts again after it
    (0.5, 0.4, None, "cyclist", None),  # a box of another class lay there: not the same object
    (0.5, 0.3, None, "person", None),   # under score_motion: never, as for motion
])
def test_a_weak_box_that_stays_put_is_an_object_once_it_stayed_long_enough(still_s, score, gap_at, class_before,
                                                                             first_object):
    config = dataclasses.replace(NETWORK_MODE, score_motion=0.35, continue_score=0.2, still_s=still_s)
    frames = 10
    boxes = [found((class_before if index < frames - 1 else "person", score, box_of(STANDER)))
             if index != gap_at else found() for index in range(frames)]
    detections = _frames_of_the_stander(config, boxes)
    objects = [index for index, found_here in enumerate(detections)
               if any(d.cls == "person" and not d.continues_only for d in found_here)]
    if first_object is None:
        assert objects == []
        assert detections[-1][0].continues_only     # still there, to carry on a track only
    else:
        assert objects == list(range(first_object, frames))


def test_a_weak_box_hides_no_big_motion_blob():
    """A weak box may find no track to carry on: the big moving blob under it stays an object."""
    tall = walker(7, tall=100)
    config = dataclasses.replace(NETWORK_MODE, score_motion=0.2, continue_score=0.1)
    big = run(config, found(("vehicle", 0.15, box_of(tall))), walker_tall=100)
    assert sorted((d.cls_source, d.continues_only) for d in big.detections) == [("network", True), ("objects", False)]


def test_a_standing_person_with_a_confident_box_is_detected_and_blobs_miss_them():
    both = found(("person", 0.9, box_of(STANDER)), ("person", 0.9, box_of(walker(7))))
    network = run(NETWORK_MODE, both)
    assert sorted(d.box[0] for d in network.detections) == [STANDER[0], walker(7)[0]]
    assert not network.foreground[STANDER[1]:STANDER[1] + STANDER[3], STANDER[0]:STANDER[0] + STANDER[2]].any()
    # The same frames in blobs mode: the walker only (the background holds the stander), and the
    # network's detections on the packet change nothing.
    blobs = run(ObjectsConfig(), both)
    assert [d.cls_source for d in blobs.detections] == ["objects"]
    assert blobs.detections[0].box[0] == pytest.approx(walker(7)[0], abs=4)
    plain = run(ObjectsConfig(), None)
    assert [d.box for d in plain.detections] == [d.box for d in blobs.detections]
    assert [d.heights for d in plain.detections] == [d.heights for d in blobs.detections]


@pytest.mark.parametrize("tall, kept", [(100, True), (60, True), (59, False), (50, False)])
def test_a_big_motion_blob_without_a_box_is_an_object_as_the_head_misses_big_ones(tall, kept):
    """A quarter of the frame tall or more (the 240 px frame: 60 px): kept without a box; the
    blob finder skips smaller blobs before measuring them, exactly at that floor."""
    at_top = dataclasses.replace(NETWORK_MODE, vehicle_height_percentile=100.0)
    big = run(at_top, found(), walker_tall=tall).detections
    assert [(d.cls_source, round(d.height(), 1), d.box[3]) for d in big] == ([("objects", 1.8, tall)] if kept else [])


def test_with_a_big_object_head_no_big_motion_blob_stands_in_for_its_boxes():
    """A network with a head of its own for big objects boxes them itself: a big blob without a
    box is then no object (it would be one of the head's misses, not a stand-in for a known gap);
    ``keep_motion_blobs`` still keeps every blob."""
    no_box = dataclasses.replace(found(), big_objects=True)
    assert run(NETWORK_MODE, no_box, walker_tall=100).detections == []
    kept = run(dataclasses.replace(NETWORK_MODE, keep_motion_blobs=True), no_box, walker_tall=100).detections
    assert [d.cls_source for d in kept] == ["objects"]
    assert motion_blob_floor(NETWORK_MODE, 240, no_box) == float("inf")
    assert motion_blob_floor(NETWORK_MODE, 240, found()) == pytest.approx(60.0)


def test_a_big_motion_blob_reads_at_the_vehicles_percentile_and_kept_blobs_at_the_top():
    """The big blobs kept in network mode are the near vehicles the head misses: measured as its
    vehicle boxes are (``vehicle_height_percentile``); with ``keep_motion_blobs`` every blob is
    kept, walkers too, and all read at ``height_percentile`` as in blobs mode."""
    def height(config):
        [blob] = run(config, found(), walker_tall=100).detections
        return blob.height()

    # The drawn walker's heights fall linearly from 1.80 m at the crown: its 80th percentile is lower.
    assert height(NETWORK_MODE) < 1.70
    assert height(dataclasses.replace(NETWORK_MODE, vehicle_height_percentile=100.0)) == pytest.approx(1.8, abs=0.05)
    assert height(dataclasses.replace(NETWORK_MODE, keep_motion_blobs=True)) == pytest.approx(1.8, abs=0.05)


def test_a_motion_blob_without_a_box_is_no_object_unless_kept():
    assert run(NETWORK_MODE, found()).detections == []
    kept = run(dataclasses.replace(NETWORK_MODE, keep_motion_blobs=True), found()).detections
    assert [(d.cls_source, round(d.height(), 1)) for d in kept] == [("objects", 1.8)]
    # A blob the network has a box for is that box's object, not a second one.
    boxed = run(dataclasses.replace(NETWORK_MODE, keep_motion_blobs=True),
                found(("cyclist", 0.9, box_of(walker(7))))).detections
    assert [(d.cls, d.cls_source) for d in boxed] == [("cyclist", "network")]


def test_a_box_mostly_inside_a_stronger_kept_box_is_a_fragment_of_it():
    x0, y0, x1, y1 = box_of(STANDER)                      # 20 x 60 px
    legs = (x0, y0 + 30, x1, y1)                          # wholly inside: the head's second peak
    beside = (x0 + 12, y0, x1 + 12, y1)                   # 40 % inside: a neighbour in a group
    kept = measure((x0, y0, x1, y1), extra=[("person", 0.8, legs), ("person", 0.8, beside)])
    assert [d.box for d in kept] == [(x0, y0, 20.0, 60.0), (x0 + 12, y0, 20.0, 60.0)]
    # The stronger box must itself be an object: a still box under its threshold suppresses nothing
    # (it is passed on, only to carry on a track).
    weak_whole = network_objects(found(("vehicle", 0.65, (x0, y0, x1, y1)), ("person", 0.6, legs)),
                                 NETWORK_MODE, 0.1, *scene([STANDER])[1:], None, EDGE)
    assert [(d.box, d.continues_only) for d in weak_whole] == [((x0, y0, 20.0, 60.0), True),
                                                              ((x0, y0 + 30, 20.0, 30.0), False)]


def test_no_network_detections_no_objects():
    """A model without a head (or a stand-in that gives none): nothing, even where things move."""
    assert run(NETWORK_MODE, None).detections == []


# ------------------------------------------------------------------ measuring one box

EDGE = np.zeros((HEIGHT, WIDTH), bool)
EDGE[:3], EDGE[-3:], EDGE[:, :3], EDGE[:, -3:] = True, True, True, True


def measure(box, people=(STANDER,), config=NETWORK_MODE, cls="cyclist", wall=False, extra=()) -> list[Detection]:
    _, heights, ground = scene(list(people))
    if wall:
        # Scenery behind the object, seen beside its head: lower than the object's own top.
        behind = heights[50:80, 30:70]
        np.maximum(behind, 1.2, out=behind)
        ground = heights < 0.1
    return network_objects(found((cls, 0.9, box), *extra), config, 0.1, heights, ground, None, EDGE)


def test_the_height_comes_from_the_box_pixels_above_the_ground():
    (detection,) = measure((35.6, 57.7, 64.4, 120.2), wall=True)
    # Robust top of the box's own pixels: 1.70 m at the crown, plus half the step to the row below.
    assert detection.height() == pytest.approx(1.70 + 0.5 * 1.65 / 59, abs=0.002)
    assert detection.heights[NETWORK].source == "objects" and 0 < detection.heights[NETWORK].noise_m < 0.5
    # The box is the network's box to the nearest pixel edges (the truth's boxes are pixel extents);
    # the ends are its own (sub-pixel) top and bottom.
    assert detection.box == (36.0, 58.0, 28.0, 62.0)
    assert detection.foot_xy == pytest.approx((50.0, 120.2)) and detection.top_xy == pytest.approx((50.0, 57.7))
    assert detection.mask.shape == (62, 28) and detection.mask.sum() == 1376   # 1160 of the person, 216 of the wall
    assert (detection.cls, detection.cls_source) == ("cyclist", "network")      # the network's class
    assert not (detection.touches_border or detection.foot_cut or detection.top_cut)


def test_a_vehicle_reads_its_roof_not_the_highest_of_its_scattered_roof_pixels():
    """v2's decoded heights scatter around a flat roof; the maximum of hundreds of them overshoots it."""
    heights = np.zeros((HEIGHT, WIDTH), np.float32)
    rng = np.random.default_rng(3)
    heights[100:120, 100:180] = 1.50 + rng.normal(0.0, 0.05, (20, 80))      # the roof, seen from above
    heights[120:150, 100:180] = np.linspace(1.0, 0.05, 30, dtype=np.float32)[:, None]   # its side
    box = (100.0, 100.0, 180.0, 150.0)

    def read(cls, **keys):
        config = dataclasses.replace(NETWORK_MODE, **keys)
        (detection,) = network_objects(found((cls, 0.9, box)), config, 0.1, heights, heights < 0.1, None, EDGE)
        return detection.height()

    assert read("vehicle") == pytest.approx(1.50, abs=0.04)                # the default: the 80th percentile
    assert read("vehicle", vehicle_height_percentile=100.0) > 1.60          # the maximum overshoots the roof
    assert read("person") == read("vehicle", vehicle_height_percentile=100.0)   # other classes: height_percentile


def test_a_network_box_has_no_outline_for_the_vehicle_box():
    """Its pixels above the ground hold whatever stands in the box, not a silhouette: the vehicle
    box (channel BOX) is fitted to blobs' outlines only."""
    (detection,) = measure(box_of(STANDER), cls="vehicle", wall=True)
    assert detection.outline is None and detection.mask.any()


def test_a_box_with_no_height_above_the_ground_is_an_object_without_a_height():
    (detection,) = measure((200, 150, 230, 200))                # nothing above the ground there
    assert detection.heights == {} and detection.cls == "cyclist"
    (tall,) = measure(box_of(STANDER), config=dataclasses.replace(NETWORK_MODE, max_object_height_m=1.5))
    assert tall.heights == {}                                   # out of the plausible range: no reading


@pytest.mark.parametrize("box, touches, top_cut, foot_cut", [
    ((40, 60, 60, 120), False, False, False),
    ((40, 0, 60, 60), True, True, False),           # the frame's top cuts the object: no height, a bound
    ((40, 180, 60, 245), True, False, True),        # runs off the bottom (clipped to the frame)
    ((-5, 60, 20, 120), True, False, False),        # the side: touches, neither end cut
])
def test_a_box_reaching_the_image_edge_is_cut_there(box, touches, top_cut, foot_cut):
    x0, y0, x1, y1 = box
    person = (max(x0, 0), y0, min(x1, WIDTH) - max(x0, 0), min(y1, HEIGHT) - y0, 1.7)
    (detection,) = measure(box, people=[person])
    assert (detection.touches_border, detection.top_cut, detection.foot_cut) == (touches, top_cut, foot_cut)
    assert 0 <= detection.box[0] and detection.box[0] + detection.box[2] <= WIDTH
    assert detection.box[1] + detection.box[3] <= HEIGHT
    assert (detection.heights[NETWORK].noise_m == np.inf) == top_cut


# ------------------------------------------------------------------ the ends from motion

BOX = np.array([100.0, 80.4, 120.0, 139.6])
"""x0, y0, x1, y1 of a walker's box that ends short of the crown (row 70) and the soles (row 160)."""


def walker_motion(top: int = 70, bottom: int = 160, gap_row: int | None = None) -> np.ndarray:
    """A walker's foreground: a body 20 px wide down to row 120, then two legs 4 px wide."""
    foreground = np.zeros((HEIGHT, WIDTH), bool)
    foreground[top:120, 100:120] = True
    foreground[120:bottom, 104:108] = foreground[120:bottom, 112:116] = True
    if gap_row is not None:
        foreground[gap_row] = False
    return foreground


@pytest.mark.parametrize("foreground, ends", [
    (walker_motion(), (70, 160)),                           # out to the crown and the soles
    (np.zeros((HEIGHT, WIDTH), bool), (80.4, 139.6)),       # still: the box's own ends
    (walker_motion(top=78, bottom=200), (78, 169)),         # at most half the box's height below
    (walker_motion(top=40), (66, 160)),                     # ... and a quarter above
    (walker_motion(gap_row=140), (70, 139.6)),              # the row next to the end does not move
    (walker_motion(gap_row=150), (70, 150)),                # a gap ends the run
])
def test_a_moving_box_ends_where_its_motion_ends(foreground, ends):
    moved = motion_ends(foreground, BOX)
    assert moved[[0, 2]] == pytest.approx(BOX[[0, 2]]) and moved[[1, 3]] == pytest.approx(ends)


def test_motion_ends_move_the_geometry_points_not_the_box():
    heights = np.zeros((HEIGHT, WIDTH), np.float32)
    heights[70:160, 100:120] = np.linspace(1.8, 0.05, 90, dtype=np.float32)[:, None]
    config = dataclasses.replace(NETWORK_MODE, motion_ends=True)
    for use, ends in ((False, (80.4, 139.6)), (True, (70, 160))):
        (detection,) = network_objects(found(("person", 0.9, tuple(BOX))), dataclasses.replace(config, motion_ends=use),
                                       0.1, heights, heights < 0.1, walker_motion(), EDGE)
        assert detection.box == (100.0, 80.0, 20.0, 60.0)
        assert (detection.top_xy[1], detection.foot_xy[1]) == pytest.approx(ends)
    # Motion running off the frame's bottom: the foot is cut there, as a box reaching it is.
    (cut,) = network_objects(found(("person", 0.9, (100, 180, 120, 230))), config, 0.1, heights, heights < 0.1,
                             walker_motion(top=170, bottom=HEIGHT), EDGE)
    assert cut.foot_xy[1] == HEIGHT and cut.foot_cut and not cut.top_cut


# ------------------------------------------------------------------ later stages keep the network's word

def test_geometry_keeps_the_networks_class_and_reclassifies_a_blobs():
    camera = camera_from_pose(640, 480, intrinsics_from_fov(640, 480, 60), 5.0, 30.0)

    def measured(source):
        detection = Detection(box=(300, 200, 40, 200), cls="vehicle", cls_source=source,
                              foot_xy=(320.0, 400.0), top_xy=(320.0, 200.0))
        GeometryMeasurer(CameraConfig()).measure(camera, [detection])
        return detection

    assert (measured("network").cls, measured("network").cls_source) == ("vehicle", "network")
    assert measured("objects").cls_source == "geometry"


def test_a_network_box_is_never_cut_along_predicted_boxes():
    def holding_two(source):
        return Detection(box=(0.0, 0.0, 60.0, 40.0), cls="vehicle", cls_source=source, mask=np.ones((40, 60), bool))

    predictions = [(2.0, 2.0, 25.0, 36.0), (33.0, 2.0, 25.0, 36.0)]
    assert len(split_by_predictions([holding_two("objects")], predictions, ["person", "person"])) == 2
    network = holding_two("network")
    assert split_by_predictions([network], predictions, ["person", "person"]) == [network]


# ------------------------------------------------------------------ configuration

def test_thresholds_come_from_the_config_and_bad_values_are_errors(tmp_path):
    assert class_thresholds(NETWORK_MODE) == {"person": 0.5, "cyclist": 0.6, "vehicle": 0.7}
    assert min_score(NETWORK_MODE) == 0.2
    with pytest.raises(ConfigError, match="objects.source"):
        ObjectExtractor(ObjectsConfig(source="detector"), GroundConfig())
    with pytest.raises(ConfigError, match="objects.score_vehicle"):
        ObjectExtractor(ObjectsConfig(source="network", score_vehicle=1.5), GroundConfig())
    for bad in (0.0, 101.0):
        with pytest.raises(ConfigError, match="objects.vehicle_height_percentile must be above 0 and at most 100"):
            ObjectExtractor(ObjectsConfig(source="network", vehicle_height_percentile=bad), GroundConfig())
    for bad in (-5.0, 0.0, 150.0):   # both modes read it (it used to take -5 and pick an arbitrary pixel)
        for source in ("blobs", "network"):
            with pytest.raises(ConfigError, match="objects.height_percentile must be above 0 and at most 100"):
                ObjectExtractor(ObjectsConfig(source=source, height_percentile=bad), GroundConfig())
    with pytest.raises(ConfigError, match="objects.still_s must be 0"):
        ObjectExtractor(ObjectsConfig(source="network", still_s=-1.0), GroundConfig())
    with pytest.raises(ConfigError, match="score_bus"):
        check_classes(NETWORK_MODE, ["person", "bus"], "model.onnx")


@pytest.mark.parametrize("inside, ring, contrast, kept", [
    (0.6, 0.0, 0.1, True),     # a walker against still ground
    (0.6, 0.6, 0.1, False),    # rain or noise: the ring moves as much as the box
    (0.6, 0.45, 0.1, True),    # a walker in light rain
    (0.6, 0.55, 0.1, False),
    (0.6, 0.6, 0.0, True),     # contrast 0: any motion confirms
    (0.2, 0.0, 0.1, False),    # under moving_share, whatever the ring
])
def test_a_weak_box_is_confirmed_only_by_motion_against_its_surroundings(inside, ring, contrast, kept):
    """A weak box is kept when its pixels move more than the ring around it (half its width each
    side, a quarter of its height above and below): rain moves everywhere, a walker does not."""
    rng = np.random.default_rng(3)
    foreground = rng.random((HEIGHT, WIDTH)) < ring
    x0, y0, x1, y1 = 100, 80, 120, 140
    foreground[y0:y1, x0:x1] = rng.random((y1 - y0, x1 - x0)) < inside
    heights = np.zeros((HEIGHT, WIDTH), np.float32)
    heights[y0:y1, x0:x1] = np.linspace(1.7, 0.05, y1 - y0, dtype=np.float32)[:, None]
    config = dataclasses.replace(NETWORK_MODE, moving_share=0.3, motion_contrast=contrast)
    weak = found(("person", 0.3, (x0, y0, x1, y1)))
    objects = network_objects(weak, config, 0.1, heights, heights < 0.1, foreground,
                              np.zeros((HEIGHT, WIDTH), bool))
    assert [d.continues_only for d in objects] == [not kept]
