"""The MCAP /tracks record: what a replay reads back is what the run wrote."""

import pytest

from core.packets import Track
from stages.track_record import build_track_record_type, encode_track_array, tracks_from_record


@pytest.mark.parametrize("updated, filled", [(True, False), (False, True), (False, False)])
def test_a_tracks_box_source_survives_the_record(updated, filled):
    record_type = build_track_record_type()
    track = Track(4, (1.0, 2.0, 3.0, 4.0), "person", 1.7, 0.05, confirmed=True, updated=updated, filled=filled)
    data = encode_track_array(record_type, 1_000_000_000, 12, 0.48, [track])
    [back] = tracks_from_record(record_type.track_array.FromString(data))
    assert (back.updated, back.filled, back.box_source) == (updated, filled, track.box_source)
    assert (back.box, back.height_m, back.confirmed) == (track.box, track.height_m, True)


def test_a_record_without_box_source_reads_as_detected():
    record_type = build_track_record_type()
    message = record_type.track_array(frame_index=0, time_s=0.0)
    message.tracks.add(id=1, class_name="person", height_m=1.7, confirmed=True)
    [back] = tracks_from_record(message)
    assert back.updated and not back.filled
