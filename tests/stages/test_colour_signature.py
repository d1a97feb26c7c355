"""A detection's colour signature and the distance between two."""

from __future__ import annotations

import numpy as np
import pytest

from stages.colour_signature import colour_signature, signature_distances

RED, BLUE, GREY = (30, 30, 200), (200, 60, 30), (128, 128, 128)     # BGR


def _street(colour=GREY) -> np.ndarray:
    image = np.zeros((120, 160, 3), np.uint8)
    image[:] = colour
    return image


def test_a_signature_sums_to_one_and_tells_red_from_blue():
    image = _street()
    image[20:100, 20:50] = RED
    image[20:100, 100:130] = BLUE
    red = colour_signature(image, (20, 20, 30, 80))
    again = colour_signature(image, (21, 22, 28, 76))
    blue = colour_signature(image, (100, 20, 30, 80))
    assert red.sum() == pytest.approx(1.0)
    distances = signature_distances([red], [again, blue])
    assert distances[0, 0] == pytest.approx(0.0, abs=1e-6)
    assert distances[0, 1] == pytest.approx(1.0, abs=1e-6)


def test_the_mask_keeps_the_street_beside_a_walker_out():
    image = _street(BLUE)
    image[20:100, 35:45] = RED                          # a thin walker in a wide box of street
    box = (20, 20, 40, 80)
    mask = np.zeros((80, 40), bool)
    mask[:, 15:25] = True
    walker = colour_signature(image, (35, 20, 10, 80))
    with_mask, without = colour_signature(image, box, mask), colour_signature(image, box)
    distances = signature_distances([walker], [with_mask, without])
    assert distances[0, 0] == pytest.approx(0.0, abs=1e-6)
    assert distances[0, 1] > 0.5


def test_a_mask_with_too_few_pixels_or_the_wrong_size_is_ignored():
    image = _street()
    image[20:100, 20:50] = RED
    whole = colour_signature(image, (20, 20, 30, 80))
    almost_empty = np.zeros((80, 30), bool)
    almost_empty[40, 15] = True
    assert np.allclose(colour_signature(image, (20, 20, 30, 80), almost_empty), whole)
    assert np.allclose(colour_signature(image, (20, 20, 30, 80), np.ones((5, 5), bool)), whole)


def test_no_signature_for_a_box_too_small_or_outside_the_image_and_nan_distances_for_it():
    image = _street()
    assert colour_signature(image, (10, 10, 2, 2)) is None
    assert colour_signature(image, (200, 10, 30, 80)) is None
    red = colour_signature(image, (20, 20, 30, 80))
    distances = signature_distances([red, None], [None, red])
    assert np.isnan(distances[0, 0]) and np.isnan(distances[1, 0]) and np.isnan(distances[1, 1])
    assert distances[0, 1] == pytest.approx(0.0, abs=1e-6)
    assert signature_distances([], [red]).shape == (0, 1)
