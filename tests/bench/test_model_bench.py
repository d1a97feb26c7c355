"""bench.model_bench: timing a v2 export, whose input size is free and whose motion-reading head
also takes the frame before (it stopped with a traceback on the shipped v2 before)."""

from __future__ import annotations

import torch

from bench.model_bench import time_onnx
from heightnet.contact_model import ContactArchitecture, ContactNet
from media import export_contact_net


def test_a_v2_export_with_a_free_size_and_two_inputs_is_timed_at_its_trained_size(tmp_path):
    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True, detection_motion=True)).eval()
    path = export_contact_net(tmp_path, net, 64, 48)
    seconds, width, height = time_onnx(path, threads=1, rounds=1, runs=1)
    assert (width, height) == (64, 48) and 0 < seconds < 10
