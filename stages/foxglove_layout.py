"""The Foxglove layout for heightpipe's MCAP: docs/foxglove_layout.json (import it in Foxglove).

Panels, for the topics ``stages/mcap_sink.py`` writes:

    frame with the track boxes and labels  (Image: /camera/image + /camera/annotations)
    height map, colour-mapped 0-5 m         (Image: /camera/height, 16UC1 millimetres)
    height per track                        (Plot: one series per confirmed track of /tracks,
                                             keyed by its id: Foxglove's dynamic series)
    height-rule events                      (Table: /events), in tabs beside the frame notes:
                                            damaged frames (Log: /capture/damage) and live frames
                                            that skipped the network (Log: /capture/network_skipped)

Built with foxglove-sdk's layout API, so the file follows Foxglove's own schema. Rebuild it
after changing this module:  python -m stages.foxglove_layout docs/foxglove_layout.json
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import foxglove.layouts as fl



@dataclass(frozen=True)
class FoxgloveLayoutConstants:
    """The layout's fixed numbers (the rule is in docs/design.md, Configuration)."""

    height_map_max_mm: float = 5000.0
    """Top of the height map's colour scale: 5 m holds people, cars and vans in distinct colours
    (a bus's roof saturates)."""


CONSTANTS = FoxgloveLayoutConstants()


def heightpipe_layout() -> fl.Layout:
    frame = fl.ImagePanel(title="Frame: tracks (height, quality colour)", config=fl.ImageConfig(
        image_mode=fl.ImageModeConfig(
            image_topic="/camera/image", calibration_topic="/camera/calibration",
            annotations={"/camera/annotations": fl.ImageAnnotationSettings(visible=True),
                         "/camera/matches": fl.ImageAnnotationSettings(visible=False)})))
    height_map = fl.ImagePanel(title="Height map (0-5 m)", config=fl.ImageConfig(
        image_mode=fl.ImageModeConfig(image_topic="/camera/height", color_mode="colormap",
                                      color_map="turbo", min_value=0.0, max_value=CONSTANTS.height_map_max_mm)))
    heights = fl.PlotPanel(title="Height per track (m)", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value="/tracks.tracks[:]{confirmed==true}", dynamic_label_field="id",
                             dynamic_value_field="height_m", label="track", show_line=True,
                             timestamp_method="receiveTime")],
        show_legend=True, legend_display="floating", y_axis_label="m", min_y_value=0.0))
    events = fl.TabContainer(tabs=[
        fl.TabItem(title="Height-rule events",
                   content=fl.TablePanel(title="Height-rule events", config=fl.TableConfig(topic_path="/events"))),
        fl.TabItem(title="Damaged frames",
                   content=fl.LogPanel(title="Damaged frames", config=fl.LogConfig(topic_to_render="/capture/damage"))),
        fl.TabItem(title="Network skipped (live)",
                   content=fl.LogPanel(title="Network skipped (live)",
                                       config=fl.LogConfig(topic_to_render="/capture/network_skipped")))])
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=3, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(proportion=3, content=frame),
            fl.SplitItem(proportion=2, content=height_map)])),
        fl.SplitItem(proportion=2, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(proportion=3, content=heights),
            fl.SplitItem(proportion=2, content=events)])),
    ]))


def layout_json() -> str:
    return heightpipe_layout().to_json() + "\n"


if __name__ == "__main__":
    Path(sys.argv[1]).write_text(layout_json())
