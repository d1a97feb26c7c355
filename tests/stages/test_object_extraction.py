"""ObjectExtractor on drawn scenes: a textured static background with moving "people"."""

from __future__ import annotations


import numpy as np
import pytest

from core.config import GroundConfig, ObjectsConfig
from core.errors import ConfigError
from core.packets import NETWORK, CameraInfo, Detection, Frame, FramePacket
from stages.object_extraction import ObjectExtractor
from stages.object_measurements import coarse_class, fit_box_to_ends, foreground_ends, moving_beyond_ends, seen_outline

WIDTH, HEIGHT = 640, 360


def _background(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(60, 120, (HEIGHT // 8, WIDTH // 8, 3), dtype=np.uint8)
    return np.kron(small, np.ones((8, 8, 1), dtype=np.uint8))


def _scene(frame: int, people: list[tuple[int, int, int, int, float]], building=True, rng=None):
    """Image, height map and ground mask with people (x, y, w, h, height_m) drawn in."""
    image = _background().copy()
    heights = np.zeros((HEIGHT, WIDTH), np.float32)
    if building:                                  # static, above ground, never moves
        heights[0:120, 500:640] = 8.0
    for x, y, w, h, height_m in people:
        # Clothes with a random pattern that moves with the person.
        texture = np.random.default_rng(int(height_m * 100)).integers(0, 255, (h // 4 + 1, w // 4 + 1, 3))
        image[y:y + h, x:x + w] = np.kron(texture, np.ones((4, 4, 1)))[:h, :w].astype(np.uint8)
        # Heights grow from 0 at the feet to height_m at the head, like a real height map.
        column = np.linspace(height_m, 0.05, h, dtype=np.float32)[:, None]
        heights[y:y + h, x:x + w] = column
    if rng is not None:
        heights += rng.normal(0, 0.01, heights.shape).astype(np.float32)
        heights = np.clip(heights, 0, None)
    ground = heights < 0.1
    return image, heights, ground


def _packet(index, image, heights=None, ground=None):
    return FramePacket(Frame(index, index / 10, image), CameraInfo(WIDTH, HEIGHT),
                       ground_mask=ground, height_map=heights)


def _run(extractor, frames, with_height=True):
    for index, people in enumerate(frames):
        image, heights, ground = _scene(index, people, rng=np.random.default_rng(index))
        packet = extractor.process(_packet(index, image, heights if with_height else None,
                                           ground if with_height else None))
    return packet


def _walk(frames: int, start_x: int = 100, speed: int = 6, height_m: float = 1.75):
    """Five empty frames for the background model, then a walker."""
    return [[]] * 5 + [[(start_x + speed * i, 150, 40, 120, height_m)] for i in range(frames)]


def test_moving_person_becomes_one_detection_with_its_height():
    # Work at half the frame's width: each work pixel is two frame pixels, so the ends checked
    # below land on exact rows (at the default 480 of 640 a work row spans 1.33 rows).
    extractor = ObjectExtractor(ObjectsConfig(work_width=320), GroundConfig())
    packet = _run(extractor, _walk(15))
    assert len(packet.detections) == 1          # the static building is not an object
    detection = packet.detections[0]
    x, y, w, h = detection.box
    assert (x, y, w, h) == pytest.approx((100 + 6 * 14, 150, 40, 120), abs=4)
    assert detection.height() == pytest.approx(1.75, abs=0.06)
    assert (detection.cls, detection.cls_source, detection.heights[NETWORK].source) == ("person", "objects", "objects")
    # Geometry points are the walker's own ends: the soles (whose heights are under the ground
    # threshold, so the height map's cut stops 2 px short) and the crown; the box reaches them too.
    assert (y, y + h) == (150, 150 + 120)
    assert detection.foot_xy == pytest.approx((x + w / 2, 150 + 120))
    assert detection.top_xy == pytest.approx((x + w / 2, 150))
    assert not detection.touches_border
    assert 0 < detection.heights[NETWORK].noise_m < 0.5
    assert detection.mask.shape == (int(h), int(w)) and detection.mask.mean() > 0.8
    assert packet.foreground.shape == (HEIGHT, WIDTH)


def test_an_object_reaching_the_bottom_edge_has_its_foot_cut():
    walker_at_bottom = [[]] * 5 + [[(100 + 6 * i, HEIGHT - 100, 40, 100, 1.75)] for i in range(10)]
    detection = _run(ObjectExtractor(ObjectsConfig(), GroundConfig()), walker_at_bottom).detections[0]
    assert detection.touches_border and detection.foot_cut and not detection.top_cut
    assert np.isfinite(detection.heights[NETWORK].noise_m)     # the network still sees its top


def test_an_object_reaching_the_top_edge_has_no_usable_height():
    walker_at_top = [[]] * 5 + [[(100 + 6 * i, 0, 40, 100, 1.75)] for i in range(10)]
    detection = _run(ObjectExtractor(ObjectsConfig(), GroundConfig()), walker_at_top).detections[0]
    assert detection.top_cut and not detection.foot_cut and detection.heights[NETWORK].noise_m == np.inf


def test_a_walker_whose_height_map_ends_below_the_frame_top_has_no_usable_height():
    """The network called the upper body ground (Oxford: a white shirt at the frame's top): the
    blob is legs only, but the moving region goes on up to the edge, so its top is no head."""
    extractor = ObjectExtractor(ObjectsConfig(), GroundConfig())
    walk = [[]] * 5 + [[(100 + 6 * i, 0, 40, 120, 1.75)] for i in range(10)]
    for index, people in enumerate(walk):
        image, heights, ground = _scene(index, people)
        heights[:40, :400] = 0.0
        ground[:40, :400] = True
        packet = extractor.process(_packet(index, image, heights, ground))
    legs = packet.detections[0]
    assert legs.box[1] >= 30                         # the blob starts below the frame's top
    assert legs.top_cut and legs.heights[NETWORK].noise_m == np.inf


def test_moving_beyond_ends_needs_an_unbroken_run_to_the_edge():
    grown = np.zeros((60, 40), bool)
    edge = np.zeros((60, 40), bool)
    edge[0], edge[-1] = True, True
    part = np.zeros((20, 10), bool)
    part[:, 2:8] = True                              # at rows 20..39, columns 10..19 of the frame
    grown[0:20, 10:20] = True                        # moving all the way up
    assert moving_beyond_ends(part, (10, 20), grown, edge) == (True, False)
    grown[8, 10:20] = False                          # a gap: the moving thing above is another
    assert moving_beyond_ends(part, (10, 20), grown, edge) == (False, False)
    grown[40:60, 10:20] = True                       # moving all the way down
    assert moving_beyond_ends(part, (10, 20), grown, edge) == (False, True)


def test_a_vehicles_outline_starts_where_each_column_was_seen_to_change():
    changed = np.zeros((30, 40), bool)
    changed[10:25, 5:35] = True                 # a car's body, rows 10-24 ...
    changed[6:10, 12:25] = True                 # ... its cabin above, rows 6-9
    part = np.zeros((24, 40), bool)             # offset (0, 3): grown by 3 rows above both
    part[0:22, 2:38] = True
    outline = seen_outline(part, (0, 3), changed)
    assert outline[:, 15].argmax() == 6 - 3 and outline[:, 30].argmax() == 10 - 3
    # A column the background model never saw change keeps the part's own extent.
    assert outline[:, 3].argmax() == 0 and outline[:, 3].sum() == 22
    assert not (outline & ~part).any()


def test_foreground_ends_are_the_crown_and_the_soles_not_the_grown_box():
    moving = np.zeros((40, 30), bool)
    moving[11:31, 12:18] = True                 # a walker: rows 11-30 move ...
    changed = moving.copy()
    changed[10, 13:17] = True                   # ... and dark hair on row 10 is marked as shadow
    moving[31:33, 12:14] = True                 # the soles, which the height map calls ground
    changed |= moving
    changed[31:35, 18:28] = True                # a cast shadow on the ground beside the feet
    moving[36:38, 12:18] = True                 # a speck below, not touching the feet
    part = np.zeros((30, 30), bool)             # offset (0, 2): the grown blob, cut to the height map
    part[5:29, 9:21] = True                     # rows 7-30: 3 rows above the crown, none below row 30
    assert foreground_ends(part, (0, 2), changed, moving, reach=3) == (10, 32)
    # The soles are followed only as far as the growth could have cut them off.
    assert foreground_ends(part, (0, 2), changed, moving, reach=1) == (10, 31)
    # Nothing moving on the part's last row (the growth below a walker): its own bottom.
    moving[29:33] = False
    assert foreground_ends(part, (0, 2), changed, moving, reach=3) == (10, 30)
    # Nothing changed in the part at all: the part's own ends.
    empty = np.zeros_like(moving)
    assert foreground_ends(part, (0, 2), empty, empty, reach=3) == (7, 30)


def test_the_black_border_of_an_undistorted_frame_cuts_like_the_frame_edge():
    """Undistortion leaves black corners: an object whose feet reach them is cut there."""
    valid = np.ones((HEIGHT, WIDTH), bool)
    valid[260:, :300] = False                        # the black region: below row 260, left of column 300
    walk = _walk(10, start_x=100, speed=6)           # feet at row 270, x 100..194: inside the black region
    extractor = ObjectExtractor(ObjectsConfig(), GroundConfig())
    for index, people in enumerate(walk):
        image, heights, ground = _scene(index, people)
        packet = _packet(index, image, heights, ground)
        packet.image_valid = valid
        packet = extractor.process(packet)
    cut = packet.detections[0]
    assert cut.foot_cut and cut.touches_border
    # The same walk with the whole frame valid: nothing is cut.
    whole = _run(ObjectExtractor(ObjectsConfig(), GroundConfig()), walk).detections[0]
    assert not (whole.foot_cut or whole.top_cut or whole.touches_border)


def test_a_primed_background_leaves_no_ghost_where_someone_stood_at_the_start():
    """A walker standing in front of a bench in the first frame leaves a ghost in a model learnt
    from that frame, and the bench makes the ghost "above ground": an object."""
    walk = [[(100 + 8 * i, 150, 40, 120, 1.75)] for i in range(30)]   # from x=100 to x=332

    def frame(index):
        image, heights, ground = _scene(index, walk[index])
        bench = heights[150:270, 90:150]
        np.maximum(bench, 0.8, out=bench)                  # static, above ground, behind the walker
        return image, heights, heights < 0.1

    def ghosts(extractor):
        """Detections in frames 0-9 that lie mostly off the walker's true box."""
        found = []
        for index in range(10):
            x, y, w, h, _ = walk[index][0]
            for d in extractor.process(_packet(index, *frame(index))).detections:
                overlap = max(0.0, min(d.box[0] + d.box[2], x + w) - max(d.box[0], x))
                if overlap < 0.5 * d.box[2]:
                    found.append((index, d.box))
        return found

    assert ghosts(ObjectExtractor(ObjectsConfig(), GroundConfig()))
    primed = ObjectExtractor(ObjectsConfig(), GroundConfig())
    primed.prime_background([frame(index)[0] for index in range(0, 30, 3)])
    assert ghosts(primed) == []


def test_a_blob_whose_bottom_stands_above_the_ground_has_no_foot():
    """Only a head and shoulders moved (the legs are hidden): its lowest point is not a foot."""
    extractor = ObjectExtractor(ObjectsConfig(), GroundConfig())
    frames = [[(100 + 6 * i, 150, 40, 120, 1.75)] for i in range(12)]
    for index, people in enumerate(frames):
        image, heights, ground = _scene(index, people)
        heights[150 + 50:150 + 120] = 0.0                  # legs: ground-level heights (not an object) ...
        image[150 + 50:150 + 120] = _background()[150 + 50:150 + 120]  # ... and background colour
        packet = extractor.process(_packet(index, image, heights, heights < 0.1))
    detection = packet.detections[0]
    assert detection.box[3] == pytest.approx(50, abs=6) and detection.foot_cut and not detection.touches_border


def test_two_people_apart_are_two_detections():
    frames = [[(60 + 5 * i, 150, 40, 120, 1.6), (400 - 5 * i, 180, 40, 110, 1.9)] for i in range(12)]
    packet = _run(ObjectExtractor(ObjectsConfig(), GroundConfig()), frames)
    heights = sorted(d.height() for d in packet.detections)
    assert heights == pytest.approx([1.6, 1.9], abs=0.06)


def test_moving_ground_level_change_is_not_an_object():
    """A shadow or light patch moves (foreground) but stays on the ground (height 0)."""
    extractor = ObjectExtractor(ObjectsConfig(), GroundConfig())
    for index in range(12):
        image, heights, ground = _scene(index, [], building=False)
        image[200:260, 50 + 10 * index:130 + 10 * index] = 20
        packet = extractor.process(_packet(index, image, heights, ground))
    assert packet.foreground.any() and packet.detections == []


def test_without_height_map_foreground_alone_gives_detections_without_height():
    packet = _run(ObjectExtractor(ObjectsConfig(), GroundConfig()), _walk(12), with_height=False)
    assert len(packet.detections) == 1
    assert packet.detections[0].heights == {}          # no height map: no network channel
    assert packet.detections[0].cls == "other"


def test_background_none_uses_the_height_map_alone():
    extractor = ObjectExtractor(ObjectsConfig(background="none"), GroundConfig())
    image, heights, ground = _scene(0, [(100, 150, 40, 120, 1.75)])
    packet = extractor.process(_packet(0, image, heights, ground))
    # The static 8 m building is above ground but taller than any mover: scenery, not an object.
    assert [round(d.height(), 1) for d in packet.detections] == [1.8]
    assert packet.foreground is None
    with_building = ObjectExtractor(ObjectsConfig(background="none", max_object_height_m=10), GroundConfig())
    assert len(with_building.process(_packet(0, image, heights, ground)).detections) == 2


@pytest.mark.parametrize("method", ["mog2", "cnt", "knn", "gsoc"])
def test_every_background_method_finds_the_walker(method):
    packet = _run(ObjectExtractor(ObjectsConfig(background=method), GroundConfig()), _walk(15))
    assert len(packet.detections) == 1


def test_unknown_background_method_is_a_config_error():
    with pytest.raises(ConfigError, match="objects.background"):
        ObjectExtractor(ObjectsConfig(background="magic"), GroundConfig())


def test_coarse_classes():
    assert coarse_class(1.75, 40, 120) == "person"
    assert coarse_class(1.5, 200, 70) == "vehicle"       # car from the side: 4.3 m long
    assert coarse_class(3.2, 150, 150) == "vehicle"      # bus
    assert coarse_class(1.8, 80, 80) == "cyclist"        # 1.8 m wide, as tall
    assert coarse_class(float("nan"), 40, 120) == "other"


def test_two_walkers_side_by_side_are_two_detections():
    """A smooth height map (like the network's) shows one hump; the foreground shows two people."""
    import cv2

    extractor = ObjectExtractor(ObjectsConfig(), GroundConfig())
    frames = [[]] * 5 + [[(100 + 5 * i, 150, 40, 120, 1.7), (146 + 5 * i, 150, 40, 120, 1.7)]
                         for i in range(8)]
    for index, people in enumerate(frames):
        image, heights, _ = _scene(index, people)
        heights = cv2.GaussianBlur(heights, (0, 0), 6)
        packet = extractor.process(_packet(index, image, heights, heights < 0.1))
    assert len(packet.detections) == 2
    lefts = sorted(d.box[0] for d in packet.detections)
    assert lefts == pytest.approx([135, 181], abs=8)   # + the growth of the foreground (3 work px)


def test_height_consistency_residual_raises_the_noise():
    """Points matched onto the person whose height changed between frames: trust this frame less."""
    from core.packets import FeatureMatches

    noises = {}
    for wobble in (0.0, 0.3):
        extractor = ObjectExtractor(ObjectsConfig(), GroundConfig())
        for index, people in enumerate(_walk(12)):
            image, heights, ground = _scene(index, people)
            if people and index % 2:
                heights[heights > 0.1] += wobble           # the height map wobbles every other frame
            packet = _packet(index, image, heights, ground)
            if people:
                x, y, w, h, _ = people[0]
                curr = np.array([[x + 5 + i, y + 10 + 8 * i] for i in range(10)], np.float32)
                packet.matches = FeatureMatches(curr - np.float32([6, 0]), curr, np.ones(10, bool))
            packet = extractor.process(packet)
        noises[wobble] = packet.detections[0].heights[NETWORK].noise_m
    assert noises[0.3] > noises[0.0] + 0.1


def test_a_global_brightness_jump_is_not_foreground():
    """Auto exposure brightening the whole view (a bus fills half of it) must not flag every pixel."""
    extractor = ObjectExtractor(ObjectsConfig(), GroundConfig())
    frames = _walk(20)
    for index, people in enumerate(frames):
        image, heights, ground = _scene(index, people, rng=np.random.default_rng(index))
        if index >= 18:
            image = np.clip(image.astype(np.float32) * 1.5, 0, 255).astype(np.uint8)
        packet = extractor.process(_packet(index, image, heights, ground))
    assert packet.foreground.mean() < 0.1
    assert [d.height() for d in packet.detections] == [pytest.approx(1.75, abs=0.06)]


def _group(x: int, y: int, count: int = 3) -> list[tuple[int, int, int, int, float]]:
    """People shoulder to shoulder, drawn as a body and a head each."""
    return [shape for i in range(count)
            for shape in ((x + 40 * i, y + 20, 40, 100, 1.5), (x + 40 * i + 14, y, 12, 20, 1.75))]


def _run_blurred(extractor, frames):
    import cv2

    for index, people in enumerate(frames):
        image, heights, _ = _scene(index, people)
        heights = cv2.GaussianBlur(heights, (0, 0), 6)     # one smooth hump, as from the network
        packet = extractor.process(_packet(index, image, heights, heights < 0.1))
    return packet


def test_a_group_walking_shoulder_to_shoulder_is_one_detection_per_person():
    frames = [[]] * 5 + [_group(100 + 5 * i, 150) for i in range(8)]
    packet = _run_blurred(ObjectExtractor(ObjectsConfig(), GroundConfig()), frames)
    lefts = sorted(d.box[0] for d in packet.detections)
    assert len(lefts) == 3
    assert lefts[1:] == pytest.approx([135 + 40 + 7, 135 + 80 + 7], abs=10)   # cut at the shoulders' middle


def test_a_group_at_the_frame_top_stays_whole():
    """Where the frame's edge may cut a blob its outline is no row of heads (a truck's roof under
    rain streaks at a 3.5 m camera's top edge was split in three)."""
    frames = [[]] * 5 + [_group(100 + 5 * i, 0) for i in range(8)]
    packet = _run_blurred(ObjectExtractor(ObjectsConfig(), GroundConfig()), frames)
    assert len(packet.detections) == 1


def test_the_foreground_does_not_depend_on_what_ran_before_in_the_process():
    """KNN samples with OpenCV's process-wide random generator; eval-tracks runs many sequences
    in one process and their results depended on the order."""
    def noisy_run(people_per_frame):
        extractor = ObjectExtractor(ObjectsConfig(), GroundConfig())
        for index, people in enumerate(people_per_frame):
            image, heights, ground = _scene(index, people)
            noise = np.random.default_rng(index).normal(0, 12, image.shape)     # sensor noise
            image = np.clip(image + noise, 0, 255).astype(np.uint8)
            packet = extractor.process(_packet(index, image, heights, ground))
        return packet.foreground

    first = noisy_run(_walk(12))
    noisy_run(_walk(12, start_x=300, speed=-5))            # something else in between
    assert np.array_equal(first, noisy_run(_walk(12)))


def test_a_noisy_night_camera_is_denoised_and_its_walker_stays_one_detection():
    """Sensor noise of 8 grey levels speckles the foreground; a median filter is switched on for it."""
    clean = _background()
    noise = np.random.default_rng(3)

    def noisy(image):
        return np.clip(image + noise.normal(0, 8, image.shape), 0, 255).astype(np.uint8)

    assert not ObjectExtractor._noisy([clean])
    assert ObjectExtractor._noisy([noisy(clean), noisy(clean)])
    config = ObjectsConfig(work_width=0)
    extractor = ObjectExtractor(config, GroundConfig())
    extractor.prime_background([noisy(clean) for _ in range(5)])
    assert extractor._denoise
    for index, people in enumerate(_walk(10)[5:]):
        image, heights, ground = _scene(index, people, rng=np.random.default_rng(index))
        packet = extractor.process(_packet(index, noisy(image), heights, ground))
    assert len(packet.detections) == 1
    assert packet.detections[0].height() == pytest.approx(1.75, abs=0.06)
    # The crown and the soles come from a second, unfiltered background model (the filter shaves them).
    assert extractor._ends_subtractor is not None
    assert (packet.detections[0].top_xy[1], packet.detections[0].foot_xy[1]) == (150, 270)
    # The foreground is the walker (40 x 120 px) and little else: unfiltered, noise adds half as much again.
    assert packet.foreground.mean() < 1.2 * (40 * 120) / (WIDTH * HEIGHT)
    # A clean camera is left alone.
    calm = ObjectExtractor(config, GroundConfig())
    calm.prime_background([clean] * 5)
    assert calm._denoise is False and calm._ends_subtractor is None


def test_the_box_runs_from_the_crown_to_the_soles_unless_the_frame_cuts_the_top():
    mask = np.zeros((30, 10), bool)
    mask[3:28, 2:8] = True                      # grown blob: rows 3-27 of the box (y 100-129)
    detection = Detection(box=(50.0, 100.0, 10.0, 30.0), top_xy=(55.0, 103.0),
                          foot_xy=(55.0, 133.0), mask=mask, outline=mask.copy())
    fit_box_to_ends(detection)
    assert detection.box == (50.0, 103.0, 10.0, 30.0)    # crown row 103 to the soles' edge 133
    assert detection.mask.shape == (30, 10) and detection.outline.shape == (30, 10)
    assert detection.mask[:25].all(axis=0).sum() == 6 and not detection.mask[25:].any()
    cut = Detection(box=(50.0, 0.0, 10.0, 30.0), top_xy=(55.0, 4.0), foot_xy=(55.0, 30.0),
                    mask=mask, top_cut=True)
    fit_box_to_ends(cut)
    assert cut.box == (50.0, 0.0, 10.0, 30.0) and cut.mask is mask
