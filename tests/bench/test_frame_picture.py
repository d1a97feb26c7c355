"""The frame picture: the chosen frame's tracks boxed where tracks.csv puts them, no others."""

import numpy as np

from bench.frame_picture import draw_tracks, frame_rows
from stages.sink_common import CLASS_COLORS_RGB

HEADER = "frame,time_s,track_id,class,x,y,w,h,score,height_m,height_std_m,height_source,frame_damaged,network_reused\n"


def test_only_the_frames_tracks_are_boxed_in_their_class_colour(tmp_path):
    tracks = tmp_path / "run.tracks.csv"
    tracks.write_text(HEADER
                      + "7,0.7,1,vehicle,100.0,200.0,60.0,40.0,0.9,1.50,0.05,fused,0,0\n"
                      + "8,0.8,2,person,300.0,100.0,20.0,50.0,0.9,1.70,0.05,fused,0,0\n")
    picture = draw_tracks(np.zeros((360, 640, 3), np.uint8), frame_rows(tracks, 7), 7, "test")
    r, g, b = CLASS_COLORS_RGB["vehicle"]
    assert (picture[200:241, 100] == (b, g, r)).all(axis=1).mean() > 0.9, "the vehicle's left edge"
    assert not picture[120:140, 300:320].any(), "frame 8's person is not drawn on frame 7"
    assert picture[:20].any(), "the banner says what the picture shows"
