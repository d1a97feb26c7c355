"""PREFIX.tracks.csv: one row per confirmed track per processed frame.

Flushed after every frame, so a crash or kill keeps every frame written before it.
Boxes are in the source's pixels (``Frame.to_source``: the run may work on scaled frames).
``frame_damaged`` is 1 on frames decoded with errors: their heights were not measured (the
track's height is carried over from clean frames) and the box may be off. ``network_reused`` is
1 on live frames that reused the last frame's network outputs to keep up: no height was measured
on them either. ``box_source`` says where the box comes from: ``detected`` this frame,
``interpolated`` between the track's detections around it (``tracking.fill_gaps_s``) or
``predicted`` by its motion filter while it coasts.
"""

from __future__ import annotations

import csv
from pathlib import Path

from core.errors import HeightpipeError
from core.packets import FramePacket
from stages.sink_common import confirmed

CSV_HEADER = ("frame", "time_s", "track_id", "class", "x", "y", "w", "h", "score",
              "height_m", "height_std_m", "height_source", "frame_damaged",
              "network_reused", "box_source")


class TrackCsvSink:
    def __init__(self, path: Path):
        self.path = Path(path)
        try:
            self._file = open(self.path, "w", newline="", encoding="utf-8")
        except OSError as exc:
            raise HeightpipeError(f"cannot write {self.path}: {exc.strerror}") from None
        self._writer = csv.writer(self._file)
        self._writer.writerow(CSV_HEADER)
        self._file.flush()

    def write(self, packet: FramePacket) -> None:
        frame = packet.frame
        for track in confirmed(packet.tracks):
            x, y, w, h = (round(v, 1) + 0.0 for v in frame.to_source(track.box))  # + 0.0: no "-0.0" at the border
            self._writer.writerow((
                frame.index, f"{frame.time_s:.4f}", track.track_id, track.cls,
                f"{x:.1f}", f"{y:.1f}", f"{w:.1f}", f"{h:.1f}", f"{track.score:.3f}",
                f"{track.height_m:.3f}", f"{track.height_std_m:.3f}", track.height_source,
                int(bool(frame.damage)), int(packet.network_reused), track.box_source))
        self._file.flush()

    def close(self) -> None:
        self._file.close()
