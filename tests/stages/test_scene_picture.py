"""The picture of a camera read from the scene: its horizon where it lies, its bars standing up."""

import numpy as np

from core.packets import HeightCamera
from stages.scene_picture import HORIZON_BGR, scene_camera_picture


def _yellow(image: np.ndarray) -> int:
    return int(np.all(np.abs(image.astype(int) - HORIZON_BGR) < 40, axis=2).sum())


def test_a_horizon_inside_the_picture_is_drawn_and_bars_stand_below_it():
    grey = np.full((240, 320), 90, np.uint8)
    shallow = HeightCamera("heads", 6.0, 10.0, 0.0, 200.0, 1.0, 0.5, 5.0, frames=30, edges=12)
    picture = scene_camera_picture(grey, shallow, 320)
    assert picture.shape == (240, 320, 3) and _yellow(picture) > 100     # f tan 10 deg = 35 px above the centre
    white = np.all(picture > 235, axis=2)
    legend = int(np.argmax(~np.all(picture[:, 0] == 0, axis=1)))     # the text's black band ends here
    rows = np.nonzero(white[legend:].any(axis=1))[0] + legend
    assert rows.min() > 120 - 35                                      # bars stand below the horizon


def test_a_steep_camera_s_horizon_above_the_picture_is_said_not_drawn():
    grey = np.full((240, 320), 90, np.uint8)
    steep = HeightCamera("heads", 6.0, 50.0, 0.0, 200.0, 1.0, 0.5, 5.0, frames=30, edges=12)
    assert _yellow(scene_camera_picture(grey, steep, 320)) == 0
    assert _yellow(scene_camera_picture(grey, steep, 640)) == 0       # frames twice as wide: focal halved here


def test_a_legend_too_wide_for_a_small_picture_breaks_at_its_separators():
    import cv2

    from stages.scene_picture import _wrapped

    line = "67 lines agreed (green: vertical; orange, pink: ground) | bars: 1.70 m | horizon 217 px above"
    lines = _wrapped([line], 0.35, 310)
    assert len(lines) > 1 and " | ".join(lines) == line
    assert all(cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.35, 1)[0][0] <= 310 for text in lines)
    assert _wrapped([line], 0.35, 2000) == [line]
