"""A frame's mirror image read by the network, mirrored back and averaged (``height.mirror``)."""

from __future__ import annotations

import numpy as np
import pytest

from media import make_tiny_contact_model, make_tiny_height_model
from core.errors import ConfigError
from core.packets import Frame
from stages.centre_detections import centre_detections
from stages.heightnet_model import HeightNetModel
from stages.mirrored_views import averaged_with_mirror, mirror_input, mirror_problem, unmirrored, unmirrored_outputs

W, H, STRIDE = 64, 48, 4


def test_a_box_read_in_the_mirror_image_comes_back_as_the_mirror_of_that_box():
    # The mirror image's head: a peak at cell (row 5, col 3), centre (14, 22) in input pixels, whose
    # box is centred 1.5 px right and 2 px above it, 8 x 16: x 11.5-19.5 in the mirror image, so
    # x 44.5-52.5 in the frame.
    centre = np.full((1, 3, H // STRIDE, W // STRIDE), -10.0, np.float32)
    centre[0, 1, 5, 3] = 2.0
    box = np.zeros((1, 4, H // STRIDE, W // STRIDE), np.float32)
    box[0, :, 5, 3] = (1.5, -2.0, 8.0, 16.0)
    found = centre_detections(unmirrored("centre_logit", centre)[0], unmirrored("box", box)[0], STRIDE, 0.5)
    assert found.classes.tolist() == [1]
    assert found.boxes.tolist() == [pytest.approx((W - 19.5, 12.0, W - 11.5, 28.0))]


def test_an_offset_read_in_the_mirror_image_points_to_the_mirror_of_its_contact_point():
    offsets = np.zeros((1, 2, H, W), np.float32)
    offsets[0, :, 10, 20] = (3.0, 7.0)                      # pixel (20, 10) -> contact (23, 17)
    back = unmirrored("offsets", offsets)
    du, dv = back[0, :, 10, W - 1 - 20]                     # the same point in the frame: (43, 10)
    assert (W - 1 - 20 + du, 10 + dv) == (W - 1 - 23, 17)
    assert np.count_nonzero(back) == 2


def test_only_the_roll_changes_sign_in_the_mirror_image():
    camera = np.array([[0.3, 0.05, 0.2, -4.0, -5.0, -3.0]], np.float32)
    assert unmirrored("camera", camera)[0].tolist() == pytest.approx([0.3, -0.05, 0.2, -4.0, -5.0, -3.0])


def test_an_output_without_a_mirror_rule_is_an_error_not_a_silent_average():
    with pytest.raises(ValueError, match="no mirror rule"):
        unmirrored("depth", np.zeros((1, 1, 4, 4), np.float32))


def test_outputs_that_already_agree_with_their_mirror_reading_are_unchanged():
    # A head reading one object at cell column 7 and, as its mirror, one at column 8 (the two
    # boxes mirror each other): the average is what either view said.
    centre = np.full((1, 3, 12, 16), -10.0, np.float32)
    centre[0, 0, 5, [7, 8]] = 3.0
    box = np.zeros((1, 4, 12, 16), np.float32)
    box[0, :, 5, 7] = (1.0, -2.0, 8.0, 16.0)
    box[0, :, 5, 8] = (-1.0, -2.0, 8.0, 16.0)
    outputs = {"centre_logit": centre, "box": box}
    mirrored = {"centre_logit": centre[..., ::-1], "box": unmirrored("box", box)}   # what the mirror image reads
    averaged = averaged_with_mirror(outputs, unmirrored_outputs(mirrored))
    assert np.array_equal(averaged["centre_logit"], centre)
    assert np.array_equal(averaged["box"], box)


def test_the_mirror_input_is_the_image_flipped_left_to_right():
    tensor = np.arange(24, dtype=np.float32).reshape(1, 2, 3, 4)
    assert np.array_equal(mirror_input(tensor)[0, 1, 2], tensor[0, 1, 2, ::-1])
    assert mirror_input(tensor).flags.c_contiguous


def test_a_width_that_is_no_whole_number_of_cells_cannot_be_mirrored():
    assert mirror_problem(320, (2, 16)) is None
    assert mirror_problem(328, (0, 0)) is None              # no detection head
    assert "stride 16" in mirror_problem(328, (2, 16))


def test_a_model_told_to_mirror_averages_each_frame_with_its_mirror_image(tmp_path):
    # The tiny model's outputs are constants, whatever the image. Its two people mirror each other
    # (cells in columns 7 and 8, boxes 27-35 and 29-37 of 64): the mirror image reads them alike.
    # Its cyclist (cell column 3) is, read in the mirror image, one at column 12, and its roll the
    # opposite roll: averaged, the cyclist is at both places at half the evidence (logits 3 and -10
    # give -3.5), and the camera has no roll.
    centre = np.full((3, 12, 16), -10.0, np.float32)
    centre[0, 5, [7, 8]] = 3.0
    centre[1, 2, 3] = 3.0
    box = np.zeros((4, 12, 16), np.float32)
    box[:, 5, 7] = (1.0, -2.0, 8.0, 16.0)
    box[:, 5, 8] = (-1.0, -2.0, 8.0, 16.0)
    path = make_tiny_contact_model(tmp_path / "det.onnx", np.zeros((H, W, 2), np.float32),
                                   np.array([0.3, 0.05, 0.2, -4.0, -5.0, -3.0]),
                                   detection=(["person", "cyclist", "vehicle"], centre, box))
    frame = Frame(0, 0.0, np.zeros((H, W, 3), np.uint8))
    plain = HeightNetModel(path, detection_min_score=0.01).infer(frame)
    both = HeightNetModel(path, detection_min_score=0.01, mirror=True).infer(frame)

    def boxes(output, cls):
        return sorted(tuple(b) for b, c in zip(output.detections.boxes.tolist(), output.detections.classes) if c == cls)

    assert boxes(plain, "person") == boxes(both, "person") == [pytest.approx((27.0, 12.0, 35.0, 28.0)),
                                                               pytest.approx((29.0, 12.0, 37.0, 28.0))]
    assert len(boxes(plain, "cyclist")) == 1
    cyclists = [(b[0] + b[2]) / 2 for b in boxes(both, "cyclist")]
    assert sorted(cyclists) == pytest.approx([3.5 * STRIDE, W - 3.5 * STRIDE])
    assert [s for s, c in zip(both.detections.scores, both.detections.classes) if c == "cyclist"] == \
        pytest.approx([1 / (1 + np.exp(3.5))] * 2)
    assert plain.camera[:3].tolist() == pytest.approx([0.3, 0.05, 0.2])
    assert both.camera[:3].tolist() == pytest.approx([0.3, 0.0, 0.2])


def test_a_mirrored_model_needs_an_input_width_of_whole_cells(tmp_path):
    whole = make_tiny_contact_model(tmp_path / "whole.onnx", np.zeros((H, W, 2), np.float32), np.zeros(6),
                                    detection=(["person"], np.zeros((1, 12, 16), np.float32),
                                               np.zeros((4, 12, 16), np.float32)))
    assert HeightNetModel(whole, mirror=True).mirror
    # Stride 3 (48 rows in 16 cells): 64 columns are 21 cells and a third.
    part = make_tiny_contact_model(tmp_path / "part.onnx", np.zeros((H, W, 2), np.float32), np.zeros(6),
                                   detection=(["person"], np.zeros((1, 16, 21), np.float32),
                                              np.zeros((4, 16, 21), np.float32)))
    assert not HeightNetModel(part).mirror
    with pytest.raises(ConfigError, match="height.mirror .* stride 3"):
        HeightNetModel(part, mirror=True)


def test_a_v1_model_is_not_mirrored(tmp_path):
    # v1's mirrored reads measured Oxford's people 8.9 -> 20.5 cm off (docs/results.md): refused.
    path = make_tiny_height_model(tmp_path / "v1.onnx")
    assert not HeightNetModel(path).mirror
    with pytest.raises(ConfigError, match="height.mirror needs a HeightNet v2 model"):
        HeightNetModel(path, mirror=True)
