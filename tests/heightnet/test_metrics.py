import math

import numpy as np

from heightnet.metrics import PixelErrors, RowMetrics, row_label


def test_pixel_errors_on_a_hand_made_example():
    errors = PixelErrors()
    errors.add(np.array([1.0, 2.0, 1.5, 0.5]), np.array([1.0, 1.0, 1.0, 1.0]))
    s = errors.summary()
    assert math.isclose(s["rmse_cm"], 100 * math.sqrt((0 + 1 + 0.25 + 0.25) / 4))
    assert math.isclose(s["mae_cm"], 100 * (0 + 1 + 0.5 + 0.5) / 4)
    assert math.isclose(s["absrel"], 0.5)
    # ratios 1, 2, 1.5, 2 -> below 1.25: 1; below 1.5625: 2; below 1.953: 2
    assert (s["delta1"], s["delta2"], s["delta3"]) == (0.25, 0.5, 0.5)
    assert all(0 <= s[k] <= 1 for k in ("delta1", "delta2", "delta3"))


def test_row_metrics_split_movers_above_ground_ground_iou_and_object_tops():
    truth = np.zeros((4, 6), np.float32)
    truth[0, 0] = np.nan
    truth[1:3, 1] = [1.8, 1.0]            # a mover, top 1.8 m
    truth[1, 4] = 3.0                     # a static object
    instance = np.zeros((4, 6), np.uint16)
    instance[1:3, 1] = 5
    pred = truth.copy()
    pred[0, 0] = 0
    pred[1, 1] = 1.6                      # top 20 cm low
    ground = ~np.isnan(truth) & (np.nan_to_num(truth) == 0)
    prob = ground.astype(np.float32)
    row = RowMetrics()
    row.add_frame(pred, prob, truth, ground, instance, visible_ids={5}, min_object_pixels=1)
    s = row.summary()
    assert s["mover_pixels"] == 2 and s["above_pixels"] == 3
    assert math.isclose(s["mover_rmse_cm"], 100 * math.sqrt(0.04 / 2), rel_tol=1e-5)
    assert s["ground_iou"] == 1.0
    assert s["objects"] == 1
    assert 18 < s["object_top_median_abs_cm"] < 22


def test_rows_snap_to_the_paper_camera_heights():
    assert row_label(3.52) == 350 and row_label(9.0) == 920 and row_label(12.0) == 1200
