"""bench.model_bench: timing a v2 export, whose input size is free and whose motion-reading head
also takes the frame before (it stopped with a traceback on the shipped v2 before)."""

from __future__ import annotations

import torch

from bench.model_bench import time_onnx
from core.config import TrainV2Config
from heightnet.contact_export import export_contact
from heightnet.contact_model import ContactArchitecture, ContactNet
from heightnet.contact_train import save_state


def test_a_v2_export_with_a_free_size_and_two_inputs_is_timed_at_its_trained_size(tmp_path):
    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True, detection_motion=True)).eval()
    state = tmp_path / "checkpoint.pt"
    save_state(state, net, torch.optim.Adam(net.parameters()), step=1, images=2,
               config=TrainV2Config(out=str(tmp_path), input_width=64, input_height=48))
    export_contact(state, tmp_path / "v2.onnx")
    seconds, width, height = time_onnx(tmp_path / "v2.onnx", threads=1, rounds=1, runs=1)
    assert (width, height) == (64, 48) and 0 < seconds < 10
