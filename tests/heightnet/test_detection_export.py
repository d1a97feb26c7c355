"""An exported HeightNet v2 detection head as the run time reads it (tiny, untrained network)."""

from __future__ import annotations

import numpy as np
import pytest

from core.config import CameraConfig, GroundConfig, ObjectsConfig
from core.packets import Frame, FramePacket
from media import export_contact_net
from stages.calibration import camera_for_run
from stages.centre_detections import centre_detections, in_frame
from stages.height_inference import HeightEstimator
from stages.heightnet_model import HeightNetModel
from stages.object_extraction import ObjectExtractor

IN_W, IN_H = 64, 64


@pytest.fixture(scope="module")
def detector(tmp_path_factory):
    """ContactNet(widths=(8, 8, 16, 16), detection=True) saved as a training state and exported, with
    its centre bias raised so that an untrained head finds peaks."""
    import torch

    from heightnet.contact_model import ContactArchitecture, ContactNet

    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True))
    with torch.no_grad():
        net.detection_head.centre.bias.fill_(1.0)
        net.detection_head.box.bias.copy_(torch.tensor([0.0, 0.0, 0.0, 0.5]))   # 16 x 26 px boxes
    net.eval()
    return export_contact_net(tmp_path_factory.mktemp("det"), net, IN_W, IN_H), net


def test_an_exported_head_gives_the_decoded_peaks_in_frame_pixels(detector):
    import torch

    path, net = detector
    model = HeightNetModel(path, threads=1, detection_min_score=0.3)
    assert model.info.detection_classes == ("person", "cyclist", "vehicle") and model.info.detection_stride == 4
    image = np.random.default_rng(0).integers(0, 255, (96, 160, 3), dtype=np.uint8)
    found = model.run(image).detections
    assert len(found) > 0, "the test network must find something"
    with torch.no_grad():
        *_, centre, box = net(torch.from_numpy(model.preprocess(image)))
    expected = in_frame(centre_detections(centre[0].numpy(), box[0].numpy(), 4, 0.3, 100),
                        model.info.detection_classes, (IN_W, IN_H), (160, 96))
    # The same peaks (those of equal score may come in either order).
    assert len(found) == len(expected)
    for box, cls, score in zip(found.boxes, found.classes, found.scores):
        same = [i for i, c in enumerate(expected.classes)
                if c == cls and np.abs(expected.boxes[i] - box).max() < 1e-2]
        assert same and abs(expected.scores[same[0]] - score) < 1e-4


def test_a_fine_head_exports_at_half_resolution_and_the_run_time_decodes_it(tmp_path):
    """A head with the fine path (``detection_fine``) writes stride 2 in its metadata; the run time
    checks its outputs against it and decodes its peaks on 2-pixel cells."""
    import torch

    from heightnet.contact_model import ContactArchitecture, ContactNet

    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True, detection_fine=True))
    with torch.no_grad():
        net.detection_head.centre.bias.fill_(1.0)
        torch.nn.init.normal_(net.detection_head.fine[2].weight, std=0.5)
    net.eval()
    model = HeightNetModel(export_contact_net(tmp_path, net, IN_W, IN_H), threads=1, detection_min_score=0.3)
    assert model.info.detection_stride == 2
    image = np.random.default_rng(0).integers(0, 255, (96, 160, 3), dtype=np.uint8)
    found = model.run(image).detections
    with torch.no_grad():
        *_, centre, box = net(torch.from_numpy(model.preprocess(image)))
    assert centre.shape[-2:] == (IN_H // 2, IN_W // 2)
    expected = in_frame(centre_detections(centre[0].numpy(), box[0].numpy(), 2, 0.3, 100),
                        model.info.detection_classes, (IN_W, IN_H), (160, 96))
    assert len(found) == len(expected) > 0
    assert np.abs(np.sort(found.boxes, 0) - np.sort(expected.boxes, 0)).max() < 1e-2


def test_network_mode_makes_objects_of_an_exported_heads_boxes(detector):
    path, _ = detector
    model = HeightNetModel(path, threads=1, detection_min_score=0.3)
    camera = camera_for_run(CameraConfig(height_m=5.0), 160, 96)
    image = np.random.default_rng(1).integers(0, 255, (96, 160, 3), dtype=np.uint8)
    packet = HeightEstimator(model, camera).process(FramePacket(Frame(0, 0.0, image), camera))
    config = ObjectsConfig(source="network", score_person=0.3, score_cyclist=0.3, score_vehicle=0.3)
    packet = ObjectExtractor(config, GroundConfig()).process(packet)
    found = packet.network_detections
    assert len(packet.detections) > 0 and {d.cls_source for d in packet.detections} == {"network"}
    # Every box the head found is an object of its class, or lies at least half inside a stronger
    # one that is (its fragment: stages.network_objects): an untrained head's boxes overlap a lot.
    kept = {(round(d.box[0]), round(d.box[1])): d.cls for d in packet.detections}
    frame_boxes = np.clip(found.boxes, 0, [160, 96, 160, 96])
    stronger = np.zeros((0, 4))
    for index, (box, cls) in enumerate(zip(frame_boxes, found.classes)):
        if kept.get((int(np.floor(box[0])), int(np.floor(box[1])))) == cls:
            stronger = np.vstack([stronger, box])
            continue
        width = np.clip(np.minimum(box[2], stronger[:, 2]) - np.maximum(box[0], stronger[:, 0]), 0, None)
        height = np.clip(np.minimum(box[3], stronger[:, 3]) - np.maximum(box[1], stronger[:, 1]), 0, None)
        assert (width * height).max() >= 0.5 * (box[2] - box[0]) * (box[3] - box[1]), f"box {index} lost"
    assert len(stronger) == len(packet.detections)


@pytest.mark.parametrize("width, size", [(0, (IN_W, IN_H)), (128, (128, 128)), (100, (96, 96)), (7, (16, 16))])
def test_an_export_runs_at_the_input_width_asked_for(detector, width, size):
    """The export's input size is free: the run time fixes it (the trained aspect, multiples of 16),
    and the offsets, ground and head come out at that size, the same as the network gives there."""
    import torch

    path, net = detector
    model = HeightNetModel(path, threads=1, detection_min_score=0.3, input_width=width)
    assert (model.info.input_width, model.info.input_height) == size
    image = np.random.default_rng(2).integers(0, 255, (96, 160, 3), dtype=np.uint8)
    output = model.run(image)
    assert output.offsets.shape == (size[1], size[0], 2)
    with torch.no_grad():
        offsets, *_ = net(torch.from_numpy(model.preprocess(image)))
    assert np.abs(output.offsets - offsets[0].numpy().transpose(1, 2, 0)).max() < 1e-3


def test_an_input_width_the_model_cannot_take_is_one_clear_error(detector, tmp_path):
    from core.errors import ConfigError, ModelError
    from media import make_tiny_contact_model

    path, _ = detector
    with pytest.raises(ConfigError, match="height.input_width"):
        HeightNetModel(path, threads=1, input_width=-1)
    fixed = make_tiny_contact_model(tmp_path / "fixed.onnx", np.zeros((48, 64, 2)), np.zeros(6))
    assert HeightNetModel(fixed, threads=1, input_width=64).info.input_width == 64
    with pytest.raises(ModelError, match="fixed 64x48 input, not 128 wide"):
        HeightNetModel(fixed, threads=1, input_width=128)


def test_a_motion_reading_head_gets_the_frame_before_from_the_run_time(tmp_path):
    """A head with a motion path exports with the frame before as a second input; the run time
    gives it the last frame it ran on (the first frame: itself, no change), and ``run`` on one
    image sees no change. Frames are as the network takes them at each call (checked against
    the PyTorch network)."""
    import torch

    from heightnet.contact_model import ContactArchitecture, ContactNet

    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True, detection_motion=True))
    with torch.no_grad():
        torch.nn.init.normal_(net.detection_head.motion[4].weight, std=0.5)
        net.detection_head.centre.bias.fill_(1.0)
    net.eval()
    model = HeightNetModel(export_contact_net(tmp_path, net, IN_W, IN_H), threads=1, detection_min_score=0.3)
    assert model.takes_previous
    rng = np.random.default_rng(3)
    first, second = (rng.integers(0, 255, (96, 160, 3), dtype=np.uint8) for _ in range(2))

    def heatmap_peaks(image, previous):
        with torch.no_grad():
            *_, centre, box = net(torch.from_numpy(model.preprocess(image)),
                                  previous=torch.from_numpy(model.preprocess(previous)))
        return in_frame(centre_detections(centre[0].numpy(), box[0].numpy(), 4, 0.3, 100),
                        model.info.detection_classes, (IN_W, IN_H), (160, 96)).scores

    def same(a, b):
        return a.shape == b.shape and np.allclose(np.sort(a), np.sort(b), atol=1e-4)

    outputs = [model.infer(Frame(index, 0.1 * index, image)) for index, image in enumerate((first, second))]
    assert same(outputs[0].detections.scores, heatmap_peaks(first, first))
    assert same(outputs[1].detections.scores, heatmap_peaks(second, first))
    assert not same(heatmap_peaks(second, first), heatmap_peaks(second, second))
    assert same(model.run(second).detections.scores, heatmap_peaks(second, second))
