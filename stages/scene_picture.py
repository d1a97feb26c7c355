"""A picture of the camera read from the scene, to check it by eye.

``heightpipe calibrate SOURCE --camera-height H --picture FILE`` prints a camera nobody can
verify from its numbers alone. The picture shows what it rests on and what it implies, on the
scene's median frame (what moves left out): the straight lines that agreed with it (vertical
edges in green, each family of parallel ground lines in its own colour), its horizon, and
1.70 m bars standing on the ground across the view, drawn with the camera read. If the bars are
as tall as the people (or the doors) beside them, the heights will be right; if they lean where
the walls do not, the roll or the pitch is off.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from core.packets import HeightCamera
from stages.calibration import camera_from_pose, horizon_line, pixel_to_ground, project_points
from stages.vertical_edges import EdgeFit

BAR_M = 1.70
VERTICAL_BGR = (60, 220, 60)
FAMILY_BGR = ((0, 160, 255), (255, 80, 255))
HORIZON_BGR = (0, 230, 255)


def scene_camera_picture(median_grey: np.ndarray, used: HeightCamera, frame_width: int,
                         fit: EdgeFit | None = None) -> np.ndarray:
    """The picture (BGR, the median's size: at most 640 wide) of camera ``used`` (focal length in
    pixels of frames ``frame_width`` wide) read from the scene whose median is ``median_grey``,
    with the lines of ``fit`` that agreed (None: the heads alone, no lines drawn)."""
    height, width = median_grey.shape[:2]
    picture = cv2.cvtColor(median_grey, cv2.COLOR_GRAY2BGR)
    focal = used.focal_px * width / frame_width
    K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    camera = camera_from_pose(width, height, K, used.height_m, used.pitch_deg, used.roll_deg)
    thickness = max(1, round(width / 320))
    if fit is not None:
        for segments, colour in ((fit.vertical, VERTICAL_BGR), *zip(fit.families, FAMILY_BGR)):
            for x1, y1, x2, y2 in np.asarray(segments, float).reshape(-1, 4):
                cv2.line(picture, (round(x1), round(y1)), (round(x2), round(y2)), colour, thickness + 1, cv2.LINE_AA)
    horizon_note = _draw_horizon(picture, horizon_line(camera), thickness)
    _draw_bars(picture, camera, thickness)
    lines = [f"camera read: pitch {used.pitch_deg:.1f} +-{used.pitch_std_deg:.1f} deg, roll {used.roll_deg:.1f} "
             f"+-{used.roll_std_deg:.1f}, focal {used.focal_px:.0f} px +-{used.focal_std_pct:.0f}%",
             f"{used.edges} lines agreed (green: vertical; orange, pink: ground"
             + (", taken as square" if used.square_families else "") + f") | bars: {BAR_M:.2f} m"
             + (f" | {horizon_note}" if horizon_note else "")]
    _draw_text(picture, lines)
    return picture


def _draw_horizon(picture: np.ndarray, line: np.ndarray, thickness: int) -> str:
    """The horizon across the picture, dashed; what to say instead when it lies outside."""
    height, width = picture.shape[:2]
    a, b, c = (float(v) for v in line)
    if abs(b) < 1e-9:
        return "horizon vertical?"
    rows = [-(a * u + c) / b for u in (0.0, width - 1.0)]
    if max(rows) < 0:
        return f"horizon {-max(rows):.0f} px above the picture"
    if min(rows) > height - 1:
        return "horizon below the picture?"
    dashes = 24
    for k in range(0, dashes, 2):
        u1, u2 = (width - 1) * k / dashes, (width - 1) * (k + 1) / dashes
        v1, v2 = (-(a * u + c) / b for u in (u1, u2))
        cv2.line(picture, (round(u1), round(v1)), (round(u2), round(v2)), HORIZON_BGR, thickness + 1, cv2.LINE_AA)
    return "yellow dashes: horizon"


def _draw_bars(picture: np.ndarray, camera, thickness: int) -> None:
    """1.70 m bars on a grid of ground points below the horizon, foot to top."""
    height, width = picture.shape[:2]
    a, b, c = (float(v) for v in horizon_line(camera))
    horizon_row = max(-(a * (width - 1) / 2 + c) / b, 0.0) if abs(b) > 1e-9 else 0.0
    top_row = max(horizon_row + 0.15 * (height - horizon_row), 0.3 * height)
    us = np.linspace(0.12, 0.88, 5) * (width - 1)
    vs = np.linspace(top_row, 0.96 * (height - 1), 3)
    foot = np.array([(u, v) for v in vs for u in us])
    ground = pixel_to_ground(camera, foot)
    ok = np.all(np.isfinite(ground), axis=1)
    tops = project_points(camera, np.column_stack([ground[ok], np.full(ok.sum(), BAR_M)]))
    for (u, v), (tu, tv) in zip(foot[ok], tops):
        if not (np.isfinite(tu) and np.isfinite(tv)):
            continue
        cv2.line(picture, (round(u), round(v)), (round(tu), round(tv)), (0, 0, 0), thickness + 3, cv2.LINE_AA)
        cv2.line(picture, (round(u), round(v)), (round(tu), round(tv)), (255, 255, 255), thickness + 1, cv2.LINE_AA)
        half = max(3, round(0.01 * width))
        cv2.line(picture, (round(u) - half, round(v)), (round(u) + half, round(v)), (255, 255, 255), thickness)


def _draw_text(picture: np.ndarray, lines: list[str]) -> None:
    scale = max(0.35, picture.shape[1] / 1400)
    lines = _wrapped(lines, scale, picture.shape[1] - 10)
    (_, line_h), _ = cv2.getTextSize("Ag", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    step = math.ceil(line_h * 1.8)
    width = max(cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] for text in lines)
    cv2.rectangle(picture, (0, 0), (width + 10, step * len(lines) + 6), (0, 0, 0), -1)
    for k, text in enumerate(lines):
        cv2.putText(picture, text, (5, step * (k + 1)), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1,
                    cv2.LINE_AA)


def _wrapped(lines: list[str], scale: float, width: int) -> list[str]:
    """Lines too wide for the picture broken at their " | " separators (a small frame's legend
    would run off its edge)."""
    def fits(text: str) -> bool:
        return cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] <= width

    out = []
    for line in lines:
        current = ""
        for part in line.split(" | "):
            joined = f"{current} | {part}" if current else part
            if current and not fits(joined):
                out.append(current)
                joined = part
            current = joined
        out.append(current)
    return out
