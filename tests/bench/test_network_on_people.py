"""The network-alone bench: readings of a height map inside labelled boxes, and their summary."""

import numpy as np
import pytest

from bench.network_on_people import BoxReading, format_table, read_box, summarise
from bench.real_heights import VIDEO, LabelledPerson


def person(box, height_m=1.8) -> LabelledPerson:
    x, y, w, h = box
    return LabelledPerson(0, np.array(box, float), np.array([x + w / 2, y]), np.array([x + w / 2, y + h]),
                          True, height_m)


def test_readings_come_from_the_box_in_map_pixels():
    height_map = np.zeros((100, 200), np.float32)
    height_map[20:80, 50:70] = np.linspace(0.0, 1.5, 60)[::-1, None]   # a walker, 1.5 m at the crown
    height_map[10, 150] = 9.0                                          # something else, outside the box
    # Labels in source pixels at twice the map's size.
    reading = read_box(height_map, person((80, 30, 80, 140)), scale=0.5)
    assert reading.max_m == pytest.approx(1.5)
    assert reading.p99_m <= reading.max_m
    assert 0.0 < reading.centre_p95_m <= 1.5
    assert reading.true_m == 1.8


def test_a_box_of_a_few_map_pixels_or_outside_the_map_reads_nothing():
    height_map = np.ones((100, 200), np.float32)
    assert read_box(height_map, person((10, 10, 6, 6)), scale=0.5) is None
    assert read_box(height_map, person((500, 10, 40, 60)), scale=0.5) is None


def test_summary_is_the_median_error_and_ratio():
    readings = [BoxReading(1.8, 1.5, 1.4, 1.3), BoxReading(1.8, 1.7, 1.6, 1.5), BoxReading(2.0, 2.1, 2.0, 1.9)]
    s = summarise(readings)
    assert s["person_frames"] == 3
    assert s["box max signed"] == pytest.approx(-0.1)          # -0.3, -0.1, +0.1
    assert s["box max abs"] == pytest.approx(0.1)
    assert s["centre p95 signed"] == pytest.approx(-0.3)       # -0.5, -0.3, -0.1
    assert s["max / true"] == pytest.approx(1.7 / 1.8)
    table = format_table({"v2": s})
    assert "| v2 | 3 | -10.0 | 10.0 |" in table


@pytest.mark.skipif(not VIDEO.is_file(), reason="needs ../shared/real/oxford_towncentre")
def test_the_shipped_network_on_oxford_reads_people_within_reason():
    from bench.network_on_people import measure

    s = measure("v2", ["capture.max_frames=10"])
    assert s["person_frames"] > 50
    # Real walkers under the network's height map: tall objects, not the ground (0) nor the sky.
    assert 1.0 < 1.8 * s["max / true"] < 2.5
