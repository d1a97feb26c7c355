"""Labels the sinks draw: what a viewer reads beside each track's box."""

import pytest

from core.packets import Track
from stages.sink_common import track_label


@pytest.mark.parametrize("box, updated, filled, expected", [
    ((0, 0, 60, 120), True, False, "1.72 m \u00b14 cm\n#12 person, geometry"),
    ((0, 0, 60, 120), False, True, "1.72 m \u00b14 cm\n#12 person, geometry, box interpolated"),
    ((0, 0, 60, 120), False, False, "1.72 m \u00b14 cm\n#12 person, geometry, box predicted"),
    ((0, 0, 5, 10), False, False, "1.72 m \u00b14 cm"),                 # no room for the second line
])
def test_a_label_says_when_no_detection_placed_the_box(box, updated, filled, expected):
    track = Track(12, box, "person", 1.72, 0.04, confirmed=True, height_source="geometry",
                  updated=updated, filled=filled)
    assert track_label(track) == expected
