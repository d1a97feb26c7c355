"""Centre-heatmap peaks -> boxes (the detection head's decoding)."""

from __future__ import annotations

import numpy as np
import pytest

from stages.centre_detections import CentreDetections, at_least_tall, box_iou, centre_detections, merged


def logit(p: float) -> float:
    return float(np.log(p / (1 - p)))


def heads(peaks: list[tuple[int, int, int, float, tuple[float, float, float, float]]], shape=(3, 10, 12)):
    centre = np.full(shape, logit(0.01), np.float32)
    box = np.zeros((4, *shape[1:]), np.float32)
    for cls, y, x, p, b in peaks:
        centre[cls, y, x] = logit(p)
        # A near neighbour that is not a local maximum must not become a second object.
        centre[cls, y, min(x + 1, shape[2] - 1)] = logit(p * 0.9)
        box[:, y, x] = b
    return centre, box


@pytest.mark.parametrize("threshold, expected", [
    (0.3, [(0, 0.9), (2, 0.5)]),
    (0.6, [(0, 0.9)]),
    (np.array([0.95, 0.3, 0.3]), [(2, 0.5)]),
])
def test_peaks_above_the_threshold_become_boxes(threshold, expected):
    centre, box = heads([(0, 2, 3, 0.9, (1.0, -2.0, 8.0, 20.0)), (2, 6, 8, 0.5, (0.0, 0.0, 30.0, 12.0))])
    found = centre_detections(centre, box, stride=4, threshold=threshold)
    assert [(int(c), round(float(s), 3)) for c, s in zip(found.classes, found.scores)] == expected
    if expected[0][0] == 0:
        # Cell (3, 2) has its centre at (14, 10) input pixels; shifted by (1, -2), 8 x 20 px.
        np.testing.assert_allclose(found.boxes[0], [11.0, -2.0, 19.0, 18.0], atol=1e-4)


def test_max_objects_keeps_the_best_scores():
    centre, box = heads([(1, 1, 1, 0.4, (0, 0, 4, 4)), (1, 5, 5, 0.8, (0, 0, 4, 4)), (0, 8, 9, 0.6, (0, 0, 4, 4))])
    found = centre_detections(centre, box, stride=4, threshold=0.3, max_objects=2)
    assert found.scores.tolist() == pytest.approx([0.8, 0.6])


def test_box_iou():
    a = np.array([[0, 0, 10, 10], [20, 20, 30, 30]], np.float32)
    b = np.array([[5, 0, 15, 10]], np.float32)
    np.testing.assert_allclose(box_iou(a, b), [[50 / 150], [0.0]], atol=1e-6)


def test_two_heads_merge_strongest_first_and_short_boxes_can_be_dropped():
    small = CentreDetections(np.array([[0, 0, 10, 20], [5, 5, 15, 45]], np.float32), np.array([0, 0]),
                             np.array([0.9, 0.4], np.float32))
    big = CentreDetections(np.array([[0, 0, 80, 100], [0, 0, 40, 30]], np.float32), np.array([2, 2]),
                           np.array([0.6, 0.95], np.float32))
    both = merged(small, big)
    assert both.scores.tolist() == pytest.approx([0.95, 0.9, 0.6, 0.4])
    assert both.classes.tolist() == [2, 0, 2, 0]
    assert both.boxes[0].tolist() == [0, 0, 40, 30]
    tall = at_least_tall(big, 64)
    assert len(tall) == 1 and tall.boxes[0].tolist() == [0, 0, 80, 100]
    assert len(merged(small, at_least_tall(big, 200))) == 2


@pytest.mark.parametrize("shape", [(3, 90, 160), (1, 1, 1), (2, 5, 2)])
def test_a_peak_is_the_largest_of_its_3x3_cells_in_its_own_class(shape):
    # OpenCV's dilation, a class at a time, gives what SciPy's 3x3 maximum filter gave (cells
    # past the border count as nothing); plateaus stay peaks.
    from scipy import ndimage

    from stages.centre_detections import _neighbourhood_max

    prob = np.random.default_rng(0).random(shape).astype(np.float32).round(1)
    expected = ndimage.maximum_filter(prob, size=(1, 3, 3), mode="constant", cval=0.0)
    np.testing.assert_array_equal(_neighbourhood_max(prob), expected)
