"""The held-out curve's view of a frame (heightnet/contact_eval.py)."""

import cv2
import numpy as np
import pytest
import torch
from fake_synth import fake_sequences

from heightnet.contact_data import build_contact_cache
from heightnet.contact_eval import _other_frame, evaluate, predict
from heightnet.contact_model import ContactArchitecture, ContactNet
from heightnet.normalisation import normalise


@pytest.mark.parametrize("t, frames, other", [(0, 2, 1), (1, 2, 0), (5, 8, 4), (0, 1, 0)])
def test_each_frame_is_compared_with_the_one_before_and_the_first_with_the_one_after(t, frames, other):
    assert _other_frame(t, frames) == other


def test_a_motion_head_is_scored_on_the_change_it_sees_at_run_time():
    """The curve used to run a motion-reading head without a frame before, so it scored the head
    as on a first frame. Given one, its boxes see the change; the offsets and camera do not."""
    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True, detection_motion=True)).eval()
    torch.nn.init.normal_(net.detection_head.motion[4].weight, std=0.5)
    torch.nn.init.normal_(net.detection_head.box.weight, std=0.1)
    torch.nn.init.normal_(net.detection_head.centre.weight, std=0.5)
    torch.nn.init.constant_(net.detection_head.centre.bias, 2.0)    # peaks above the curve's score
    rng = np.random.default_rng(0)
    frame, before = (rng.integers(0, 255, (48, 64, 3), dtype=np.uint8) for _ in range(2))
    alone = predict(net, frame, 64, 48)
    still = predict(net, frame, 64, 48, previous_rgb=frame)
    moved = predict(net, frame, 64, 48, previous_rgb=before)
    np.testing.assert_array_equal(alone[0], moved[0])          # offsets
    np.testing.assert_array_equal(alone[1], moved[1])          # camera heads
    assert len(alone[2]) > 0
    np.testing.assert_array_equal(alone[2].scores, still[2].scores)
    assert not np.array_equal(alone[2].scores, moved[2].scores)


@pytest.mark.parametrize("reads_motion", [True, False])
def test_the_curve_gives_a_motion_head_the_other_frame_of_each_pair_and_no_other_head_any(tmp_path, reads_motion):
    sequences = build_contact_cache(fake_sequences(count=1, frames=2, width=64, height=48), tmp_path)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True, detection_motion=reads_motion))
    seen = []
    forward = net.forward
    net.forward = lambda image, channels=None, window=None, previous=None: (
        seen.append(None if previous is None else previous.clone()) or forward(image, channels, window, previous))
    evaluate(net, sequences, 64, 48)
    if not reads_motion:
        assert seen == [None, None]
        return
    frames = [torch.from_numpy(normalise(cv2.resize(np.asarray(sequences[0].rgb[t]), (64, 48),
                                                    interpolation=cv2.INTER_AREA)))[None] for t in range(2)]
    assert torch.equal(seen[0], frames[1]) and torch.equal(seen[1], frames[0])
