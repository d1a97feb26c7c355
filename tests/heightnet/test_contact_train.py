"""HeightNet v2 data, training, resume, evaluation and export on the tiny fake synth sequences."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from fake_synth import fake_sequences
from stages.ground_contact import heights_from_offsets
from heightnet.contact_data import ContactPairDataset, ContactSampling, build_contact_cache
from heightnet.contact_eval import evaluate
from heightnet.contact_export import export_contact
from core.config import TrainV2Config
from heightnet.contact_train import (architecture_of, learning_rate, load_state, pair_previous, train_contact,
                                     training_batch)
from heightnet.normalisation import normalise
from heightnet.train import collate
from heightnet.contact_model import ContactNet


@pytest.fixture(scope="module")
def contact_sequences(tmp_path_factory):
    return build_contact_cache(fake_sequences(count=2, frames=3, width=128, height=96),
                               tmp_path_factory.mktemp("contact_cache"))


def small_config(out, **kw) -> TrainV2Config:
    kw = {"head_only": False, "detection_blocks": 0, **kw}   # a fresh run: the whole network trains
    return TrainV2Config(out=str(out), input_width=64, input_height=64, steps=4, batch_size=2,
                              threads=1, checkpoint_every=2, log_every=1, eval_every=2,
                              widths=[8, 8, 16, 16], **kw)


@pytest.mark.parametrize("sampling", [ContactSampling(), ContactSampling(crop_probability=1.0),
                                      ContactSampling(zoom_probability=1.0),
                                      ContactSampling(camera_channels=True)])
def test_samples_decode_to_their_own_heights(contact_sequences, sampling):
    """Whatever the window, flip and squash, the sample's offsets decode with the sample's camera
    to the sample's heights (to nearest-neighbour resampling of the labels)."""
    dataset = ContactPairDataset(contact_sequences, 64, 48, sampling, seed=3)
    from stages.ground_contact import PinholeCamera
    for item in range(len(dataset)):
        sample = dataset[item]
        camera = PinholeCamera(sample["K"].astype(np.float64), sample["R"].astype(np.float64),
                               sample["C"].astype(np.float64))
        for frame in range(2):
            offsets = sample["offsets"][frame].transpose(1, 2, 0)
            truth = sample["height"][frame, 0]
            labelled = np.isfinite(offsets[..., 0]) & np.isfinite(truth)
            decoded = heights_from_offsets(camera, np.nan_to_num(offsets))
            movers = labelled & (sample["instance"][frame, 0] > 0)
            assert movers.sum() > 0
            # float16 storage and the resampling's sub-pixel shift: a few centimetres at most.
            assert np.median(np.abs(decoded - truth)[movers]) < 0.03
        assert sample["image"].shape == (2, 3, 48, 64)
        assert sample["camera_valid"] == (sampling.crop_probability == 0 and sampling.zoom_probability == 0)
        assert ("camera_channels" in sample) == sampling.camera_channels


def test_still_pairs_show_one_frame_twice_and_leave_the_other_pairs_as_drawn(contact_sequences):
    """A still pair is the pair's second frame twice (no motion anywhere, its labels both the
    second frame's, no matched points); with the option at 0 every pair is drawn bit for bit as
    before it existed (its draw is made only where asked for), so committed runs reproduce."""
    plain = ContactPairDataset(contact_sequences, 64, 48, ContactSampling(detection=True), seed=3)
    never = ContactPairDataset(contact_sequences, 64, 48, ContactSampling(detection=True, still_pairs=0.0), seed=3)
    always = ContactPairDataset(contact_sequences, 64, 48, ContactSampling(detection=True, still_pairs=1.0), seed=3)
    for item in range(len(plain)):
        before, same, still = plain[item], never[item], always[item]
        for key in before:
            assert np.array_equal(before[key], same[key], equal_nan=True), key
        for key in ("image", "height", "instance", "det_centre", "det_box"):
            assert np.array_equal(still[key][0], still[key][1], equal_nan=True), key
        # Its frame is the pair's second: the same instances as the plain pair's second frame.
        assert np.array_equal(still["instance"][1], before["instance"][1])
        assert not still["match_valid"].any() and before["match_valid"].any()
        assert not np.array_equal(before["image"][0], before["image"][1])


def test_zoomed_windows_enlarge_the_objects_and_leave_the_other_pairs_as_drawn(contact_sequences):
    """A zoomed window is smaller than the input and enlarged to it, so its objects' boxes are
    bigger than in the same pair drawn whole; with the option at 0 every pair is drawn bit for bit
    as before it existed (committed runs reproduce)."""
    sampling = ContactSampling(detection=True, crop_probability=0.5)
    plain = ContactPairDataset(contact_sequences, 64, 48, sampling, seed=3)
    never = ContactPairDataset(contact_sequences, 64, 48, dataclasses.replace(sampling, zoom_probability=0.0), seed=3)
    always = ContactPairDataset(contact_sequences, 64, 48, dataclasses.replace(sampling, zoom_probability=1.0), seed=3)
    whole = ContactPairDataset(contact_sequences, 64, 48, ContactSampling(detection=True), seed=3)

    def heights(sample):
        centres = np.argwhere(sample["det_centre"][1].max(0) == 1.0)
        return [float(np.exp(sample["det_box"][1][3, j, i])) for j, i in centres]

    zoomed, squashed = [], []
    for item in range(len(plain)):
        before, same = plain[item], never[item]
        for key in before:
            assert np.array_equal(before[key], same[key], equal_nan=True), key
        sample = always[item]
        assert not sample["camera_valid"] and sample["image"].shape == (2, 3, 48, 64)
        zoomed += heights(sample)
        squashed += heights(whole[item])
    assert zoomed and squashed and np.median(zoomed) > 2.0 * np.median(squashed)


def test_resumed_training_equals_an_uninterrupted_run(contact_sequences, tmp_path):
    whole = train_contact(small_config(tmp_path / "whole"), contact_sequences, progress=False)
    train_contact(small_config(tmp_path / "split"), contact_sequences, progress=False, max_steps=2)
    resumed = train_contact(small_config(tmp_path / "split"), contact_sequences, progress=False,
                            resume=True)
    assert resumed["step"] == whole["step"] == 4
    for key in ("net", "ema"):
        for a, b in zip(whole[key].state_dict().values(), resumed[key].state_dict().values()):
            # Adam's moments pass through float16 in the committed state: equal to a small tolerance.
            assert torch.allclose(a.float(), b.float(), atol=2e-3)
    moved = [not torch.equal(a, b) for a, b in zip(whole["ema"].state_dict().values(),
                                                    whole["net"].state_dict().values())]
    assert any(moved)      # the average lags the last step
    with pytest.raises(FileExistsError):
        train_contact(small_config(tmp_path / "whole"), contact_sequences, progress=False)


def test_loader_processes_train_exactly_as_the_loop_alone(contact_sequences, tmp_path):
    """Pairs prepared by loader processes (a GPU machine's set-up) are the loop's own pairs in
    the loop's order: the same weights after the same steps."""
    alone = train_contact(small_config(tmp_path / "alone"), contact_sequences, progress=False)
    loaded = train_contact(small_config(tmp_path / "loaded", loader_workers=2), contact_sequences,
                           progress=False)
    for a, b in zip(alone["net"].state_dict().values(), loaded["net"].state_dict().values()):
        assert torch.equal(a, b)


def test_a_training_batch_is_widened_where_the_network_runs(contact_sequences):
    """Pairs travel compact (uint8 images, float16 labels); the loop's batch is what the network
    and losses always took: images normalised bit for bit as at inference, float32 labels."""
    dataset = ContactPairDataset(contact_sequences, 64, 48, ContactSampling(detection=True), seed=3)
    sample = dataset[0]
    compact = (sample["image"].dtype, sample["offsets"].dtype, sample["instance"].dtype)
    assert compact == (np.uint8, np.float16, np.int32)
    batch = training_batch(collate([sample, dataset[1]]), torch.device("cpu"))
    rgb = sample["image"][1].transpose(1, 2, 0)
    assert np.array_equal(batch["image"][0, 1].numpy(), normalise(rgb))
    assert batch["offsets"].dtype == batch["height"].dtype == batch["ground"].dtype == torch.float32
    assert batch["instance"].dtype == torch.int64
    assert np.array_equal(batch["height"][0].numpy(), sample["height"].astype(np.float32), equal_nan=True)


def test_a_time_limit_stops_with_the_state_written(contact_sequences, tmp_path):
    result = train_contact(small_config(tmp_path / "run"), contact_sequences, progress=False, max_seconds=0)
    assert result["step"] == 1   # the first step runs, then the limit is seen
    state = torch.load(tmp_path / "run" / "checkpoint.pt", map_location="cpu", weights_only=False)
    assert state["step"] == 1
    resumed = train_contact(small_config(tmp_path / "run"), contact_sequences, progress=False, resume=True)
    assert resumed["step"] == 4


def test_training_on_an_unavailable_device_is_one_clear_error(contact_sequences, tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    with pytest.raises(ValueError, match="sees no CUDA GPU"):
        train_contact(small_config(tmp_path / "run", device="cuda"), contact_sequences, progress=False)
    with pytest.raises(ValueError, match="must be 'cpu' or 'cuda'"):
        train_contact(small_config(tmp_path / "run2", device="tpu"), contact_sequences, progress=False)


def test_cache_built_by_processes_equals_the_serial_cache(tmp_path):
    sequences = fake_sequences(count=3, frames=2, width=64, height=48)
    serial = build_contact_cache(sequences, tmp_path / "serial")
    parallel = build_contact_cache(sequences, tmp_path / "parallel", workers=2)
    for a, b in zip(serial, parallel):
        assert a.name == b.name
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.match_points, b.match_points)
        assert np.array_equal(a.offsets, b.offsets, equal_nan=True)


def _open_files_named(name: str) -> int:
    return sum(Path(os.readlink(fd)).name == name for fd in Path("/proc/self/fd").iterdir()
               if fd.is_symlink() and os.path.exists(os.readlink(fd)))


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="counts open files in /proc")
def test_a_cached_sequence_is_one_file_mapped_once_holding_every_array(tmp_path):
    from heightnet.contact_data import ARRAYS_FILE

    sequences = fake_sequences(count=3, frames=2, width=64, height=48)
    before = _open_files_named(ARRAYS_FILE)
    cached = build_contact_cache(sequences, tmp_path)
    assert _open_files_named(ARRAYS_FILE) - before == 3          # one a sequence, not one an array
    for sequence, cache in zip(sequences, cached):
        assert sorted(p.name for p in (tmp_path / sequence.name).iterdir()) == [ARRAYS_FILE, "done.json", "meta.json"]
        assert np.array_equal(cache.rgb[1], sequence.frame(1).rgb)
        assert np.array_equal(cache.height_m[0], sequence.frame(0).height_m.astype(np.float16), equal_nan=True)
        assert np.array_equal(cache.instance[1], sequence.frame(1).instance)
        assert cache.matches(0).shape[1] == 4 and not cache.rgb.flags.writeable
        for t in range(len(sequence)):
            whole = cache.whole_boxes(t)
            assert sorted(whole) == sorted(o.id for o in sequence.objects(t))
            for o in sequence.objects(t):
                x, y, w, h = o.box
                assert whole[o.id] == pytest.approx((x, y, x + w, y + h, o.visible_fraction), abs=1e-4)


@pytest.mark.parametrize("version", [1, 2])
def test_a_cache_of_an_older_layout_is_rebuilt(tmp_path, version):
    sequence = fake_sequences(count=1, frames=2, width=64, height=48)[0]
    old = tmp_path / sequence.name
    old.mkdir()
    np.save(old / "rgb.npy", np.zeros((2, 48, 64, 3), np.uint8))
    (old / "done.json").write_text(json.dumps({"version": version, "frames": 2}))
    cache = build_contact_cache([sequence], tmp_path)[0]
    assert not list(old.glob("*.npy"))
    assert np.array_equal(cache.rgb[0], sequence.frame(0).rgb)
    assert len(cache.whole_boxes(1)) == len(sequence.objects(1))


def test_resume_logs_each_step_once_after_a_stop_between_checkpoints(contact_sequences, tmp_path):
    config = small_config(tmp_path / "run")
    train_contact(config, contact_sequences, contact_sequences[:1], progress=False, max_steps=3)
    # A call's end checkpoints, so stand for a run killed at step 3 after its checkpoint at 2 by
    # putting a 2-step run's state under the 3-step logs.
    train_contact(small_config(tmp_path / "two"), contact_sequences, progress=False, max_steps=2)
    (tmp_path / "two" / "checkpoint.pt").replace(tmp_path / "run" / "checkpoint.pt")
    train_contact(config, contact_sequences, contact_sequences[:1], progress=False, resume=True)
    steps = [line.split(",")[0] for line in (tmp_path / "run" / "log.csv").read_text().splitlines()[1:]]
    curve = [line.split(",")[0] for line in (tmp_path / "run" / "curve.csv").read_text().splitlines()[1:]]
    assert steps == ["1", "2", "3", "4"]
    assert curve == ["2", "4"]


def test_resume_refuses_another_architecture(contact_sequences, tmp_path):
    train_contact(small_config(tmp_path / "run"), contact_sequences, progress=False, max_steps=2)
    with pytest.raises(ValueError, match="cannot resume"):
        train_contact(small_config(tmp_path / "run", trunk="depthwise"), contact_sequences,
                      progress=False, resume=True)


def test_training_logs_losses_and_the_held_out_curve(contact_sequences, tmp_path):
    train_contact(small_config(tmp_path / "run"), contact_sequences, contact_sequences[:1], progress=False)
    log = (tmp_path / "run" / "log.csv").read_text().splitlines()
    curve = (tmp_path / "run" / "curve.csv").read_text().splitlines()
    assert len(log) == 5 and log[0].startswith("step,images")
    assert len(curve) == 3 and "rmse_cm" in curve[0]
    total = [float(row.split(",")[3]) for row in log[1:]]
    assert all(math.isfinite(v) for v in total)
    rows = list(csv.DictReader((tmp_path / "run" / "log.csv").open()))
    assert all(0.0 <= float(row["waiting_share"]) <= 1.0 for row in rows)
    net = ContactNet(architecture_of(small_config(tmp_path)))
    step, images, _ = load_state(tmp_path / "run" / "checkpoint.pt", net, None)
    assert (step, images) == (4, 16)
    assert (tmp_path / "run" / "checkpoint.pt").stat().st_size < 1_000_000


def test_evaluation_of_exact_offsets_and_camera_scores_near_zero(contact_sequences):
    """A stand-in network that returns the exact offsets and camera scores ~0 both ways; an
    untrained network does not."""
    from heightnet.contact_data import camera_targets

    width, height = 64, 64
    answers = []
    for seq in contact_sequences:
        _, src_h, src_w, _ = seq.rgb.shape
        camera = seq.camera.window(0, 0, src_w, src_h, width, height)
        target = np.concatenate([camera_targets(camera, height), np.full(3, -10.0, np.float32)])
        for t in range(2):
            offsets = cv2.resize(np.nan_to_num(np.asarray(seq.offsets[t], np.float32)), (width, height),
                                 interpolation=cv2.INTER_NEAREST_EXACT) * np.float32([width / src_w, height / src_h])
            answers.append((offsets, target))

    class Exact(torch.nn.Module):
        arch = None

        def forward(self, image, channels=None):
            offsets, camera = answers.pop(0)
            return (torch.from_numpy(offsets).permute(2, 0, 1)[None], None, torch.from_numpy(camera)[None])

    exact = evaluate(Exact(), contact_sequences, width, height)
    assert not answers
    assert exact.rmse_cm["all"] < 5 and exact.rmse_heads_cm["all"] < 5
    assert exact.pitch_error_deg < 1e-3 and exact.focal_error_pct < 1e-3
    untrained = evaluate(ContactNet(architecture_of(small_config("x"))), contact_sequences, width, height)
    assert untrained.rmse_cm["all"] > 50


def test_export_matches_pytorch_and_says_what_it_outputs(contact_sequences, tmp_path):
    import onnxruntime as ort

    train_contact(small_config(tmp_path / "run"), contact_sequences, progress=False, max_steps=1)
    report = export_contact(tmp_path / "run" / "checkpoint.pt", tmp_path / "v2.onnx")
    assert max(report["offsets"], report["ground_logit"], report["camera"], report["centre_logit"],
               report["box"]) < 1e-3
    session = ort.InferenceSession(str(tmp_path / "v2.onnx"), providers=["CPUExecutionProvider"])
    meta = session.get_modelmeta().custom_metadata_map
    assert meta["heightpipe.output_units"] == "ground_contact_offsets"
    assert meta["heightpipe.trained_images"] == "4"
    assert [o.name for o in session.get_outputs()] == ["offsets", "ground_logit", "camera", "centre_logit", "box"]
    assert json.loads(meta["heightpipe.outputs"])["centre_logit"]["classes"] == ["person", "cyclist", "vehicle"]


def test_a_big_object_head_exports_and_its_peaks_join_the_small_heads_strongest_first(contact_sequences, tmp_path):
    """The big-object head's outputs are exported and declared (stride 16); the run time decodes
    them beside the small head's, one list, strongest first, in frame pixels."""
    import onnxruntime as ort

    from stages.heightnet_model import HeightNetModel

    train_contact(small_config(tmp_path / "run", detection=True), contact_sequences, progress=False, max_steps=1)
    train_contact(small_config(tmp_path / "run", detection=True, detection_big=True, big_head_only=True),
                  contact_sequences, resume=True, progress=False, max_steps=1)
    path = tmp_path / "run" / "checkpoint.pt"
    state = torch.load(path, weights_only=False)
    big = "detection_head.big."
    for name in ("centre.weight", "box.weight"):
        state["ema"][big + name].zero_()
    state["ema"][big + "centre.bias"].copy_(torch.tensor([-20.0, -20.0, 5.0]))   # sure of a vehicle everywhere
    state["ema"][big + "box.bias"].copy_(torch.tensor([0.0, 0.0, math.log(48 / 16), math.log(64 / 16)]))
    state["ema"]["detection_head.centre.bias"].fill_(-20.0)                      # the small head sees nothing
    torch.save(state, path)
    report = export_contact(path, tmp_path / "big.onnx")
    assert max(report["big_centre_logit"], report["big_box"]) < 1e-3
    session = ort.InferenceSession(str(tmp_path / "big.onnx"), providers=["CPUExecutionProvider"])
    assert [o.name for o in session.get_outputs()][-2:] == ["big_centre_logit", "big_box"]
    outputs = json.loads(session.get_modelmeta().custom_metadata_map["heightpipe.outputs"])
    assert outputs["big_centre_logit"] == {"classes": ["person", "cyclist", "vehicle"], "stride": 16}
    model = HeightNetModel(tmp_path / "big.onnx")
    assert (model.info.detection_stride, model.info.big_detection_stride) == (2, 16)
    found = model.run(np.zeros((128, 256, 3), np.uint8)).detections   # the 64x64 input, 4 x 4 big cells
    assert len(found) == 16 and set(found.classes) == {"vehicle"} and found.big_objects
    assert np.all(np.diff(found.scores) <= 0)
    widths, heights = found.boxes[:, 2] - found.boxes[:, 0], found.boxes[:, 3] - found.boxes[:, 1]
    assert np.allclose(widths, 48 * 4) and np.allclose(heights, 64 * 2)           # frame = 4x, 2x the input
    assert np.allclose(np.sort(np.unique((found.boxes[:, 0] + found.boxes[:, 2]) / 2)), [32, 96, 160, 224])
    # Boxes shorter than what the head was taught (``big_min_height_px``, input pixels) are dropped.
    state["ema"][big + "box.bias"][3] = math.log(40 / 16)
    torch.save(state, path)
    export_contact(path, tmp_path / "short.onnx")
    assert len(HeightNetModel(tmp_path / "short.onnx").run(np.zeros((128, 256, 3), np.uint8)).detections) == 0


def test_a_grown_network_starts_as_the_state_it_grew_from(contact_sequences, tmp_path):
    """Context blocks, the detection head, the refinement, the gate and the position channels
    start as no-ops: resuming a smaller network's state with them gives the same offsets, then
    trains on, with the warm-up restarted and the logs widened."""
    small = small_config(tmp_path / "run", context=[], detection=False, refine=0, gate=False, position=False)
    before = train_contact(small, contact_sequences, contact_sequences, progress=False, max_steps=2)
    grown_config = small_config(tmp_path / "run", context=[2, 4], detection=True, refine=4, gate=True,
                                position=True)
    net = ContactNet(architecture_of(grown_config))
    step, images, warmup_from = load_state(tmp_path / "run" / "checkpoint.pt", net, None, grown_config)
    assert (step, warmup_from) == (2, 2)
    net.eval()
    before["net"].eval()
    x = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        old, new = before["net"](x)[0], net(x)[0]
        cropped = net(x, None, torch.tensor([[0.2, 0.5, -0.4, 0.5]]))[0]
    assert torch.allclose(old, new, atol=1e-5)
    assert torch.allclose(old, cropped, atol=1e-5)
    after = train_contact(grown_config, contact_sequences, contact_sequences, resume=True, progress=False,
                          max_steps=2)
    assert after["step"] == 4
    with open(tmp_path / "run" / "log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["step"] for r in rows] == ["1", "2", "3", "4"]
    assert rows[0]["centre"] == "nan" and rows[-1]["centre"] != "nan"
    with open(tmp_path / "run" / "curve.csv", newline="") as f:
        curve = list(csv.DictReader(f))
    assert [r["step"] for r in curve] == ["2", "4"]
    assert curve[0]["det_recall_person"] == "nan" and curve[1]["det_recall_person"] != "nan"
    with pytest.raises(ValueError, match="cannot resume"):
        load_state(tmp_path / "run" / "checkpoint.pt", ContactNet(architecture_of(small)), None, small)


def test_head_only_training_moves_the_head_and_nothing_else(contact_sequences, tmp_path):
    """With ``head_only`` the rest of the network keeps the averaged weights it resumed with
    (BatchNorm statistics included) in the trained and the averaged copy; the head learns."""
    first = train_contact(small_config(tmp_path / "run", detection=True), contact_sequences, progress=False,
                          max_steps=2)
    start = {k: v.clone() for k, v in first["ema"].state_dict().items()}
    after = train_contact(small_config(tmp_path / "run", detection=True, detection_blocks=1, head_only=True),
                          contact_sequences, resume=True, progress=False, max_steps=2)
    for name, value in after["ema"].state_dict().items():
        if name.startswith("detection_head."):
            continue
        assert torch.equal(value, start[name]), name
        assert torch.equal(after["net"].state_dict()[name], start[name]), name
    head = [k for k in start if k.startswith("detection_head.trunk.")]
    assert any(not torch.equal(after["net"].state_dict()[k], start[k]) for k in head)
    with pytest.raises(ValueError, match="head_only"):
        train_contact(small_config(tmp_path / "fresh", head_only=True), contact_sequences, progress=False,
                      max_steps=1)


def test_big_head_only_training_grows_the_big_object_head_and_moves_nothing_else(contact_sequences, tmp_path):
    """``big_head_only`` grows the big-object head onto a trained state and trains it alone: the
    small head too keeps its weights bit for bit (what it finds cannot change), and the grown
    network's small-head outputs are the old network's."""
    first = train_contact(small_config(tmp_path / "run", detection=True), contact_sequences, progress=False,
                          max_steps=2)
    start = {k: v.clone() for k, v in first["ema"].state_dict().items()}
    grown = small_config(tmp_path / "run", detection=True, detection_big=True, big_head_only=True)
    after = train_contact(grown, contact_sequences, resume=True, progress=False, max_steps=2)
    for name, value in after["ema"].state_dict().items():
        if name.startswith("detection_head.big."):
            continue
        assert torch.equal(value, start[name]), name
        assert torch.equal(after["net"].state_dict()[name], start[name]), name
    big = [k for k in after["net"].state_dict() if k.startswith("detection_head.big.")]
    fresh = ContactNet(architecture_of(grown)).state_dict()
    assert big and any(not torch.equal(after["net"].state_dict()[k], fresh[k]) for k in big)
    image = torch.randn(1, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    first["ema"].eval()
    after["ema"].eval()
    with torch.no_grad():
        old, new = first["ema"](image), after["ema"](image)
    assert len(old) == 5 and len(new) == 7
    for a, b in zip(old, new):
        assert torch.equal(a, b)
    assert new[5].shape == (1, 3, 4, 4) and new[6].shape == (1, 4, 4, 4)
    rows = list(csv.DictReader((tmp_path / "run" / "log.csv").open()))
    assert rows[-1]["big_centre"] not in ("", "nan")
    train_contact(small_config(tmp_path / "plain", detection=True), contact_sequences, progress=False, max_steps=1)
    with pytest.raises(ValueError, match="needs the big-object head"):
        train_contact(small_config(tmp_path / "plain", detection=True, big_head_only=True), contact_sequences,
                      resume=True, progress=False, max_steps=1)


def test_each_image_of_a_pair_gets_the_other_as_its_frame_before():
    images = torch.arange(2 * 2 * 3 * 4 * 4, dtype=torch.float32).view(2, 2, 3, 4, 4)   # B=2 pairs
    previous = pair_previous(images)
    flat = images.flatten(0, 1)                                                        # t-1, t, t-1, t
    assert previous.shape == flat.shape
    for pair in range(2):
        assert torch.equal(previous[2 * pair], flat[2 * pair + 1])
        assert torch.equal(previous[2 * pair + 1], flat[2 * pair])


def test_a_head_grown_with_the_motion_path_learns_it(contact_sequences, tmp_path):
    """A head-only run that asks for ``detection_motion`` grows it onto a trained state (starting at
    zero, so the first step sees the old head) and trains it on each pair's other frame."""
    train_contact(small_config(tmp_path / "run", detection=True), contact_sequences, progress=False, max_steps=2)
    after = train_contact(small_config(tmp_path / "run", detection=True, detection_motion=True, head_only=True),
                          contact_sequences, resume=True, progress=False, max_steps=2)
    assert after["net"].detection_head.motion[4].weight.abs().sum() > 0


def test_the_camera_heads_measurement_stays_with_head_only_training_and_no_other(contact_sequences, tmp_path,
                                                                                 capsys):
    """``camera_fresh --write`` measures the frozen camera heads: a head-only run keeps that in every
    state it writes (the export puts it in the model); a run that trains the heads drops it and
    says to measure again (a resumed head-only run once exported models without it)."""
    train_contact(small_config(tmp_path / "run", detection=True), contact_sequences, progress=False, max_steps=2)
    path = tmp_path / "run" / "checkpoint.pt"
    state = torch.load(path, weights_only=False)
    state.update(camera_spread_scale=[2.0, 1.0, 2.5], camera_error_correlation=np.eye(3).tolist())
    torch.save(state, path)
    train_contact(small_config(tmp_path / "run", detection=True, head_only=True), contact_sequences,
                  resume=True, progress=False, max_steps=2)
    kept = torch.load(path, weights_only=False)
    assert kept["step"] == 4 and kept["camera_spread_scale"] == [2.0, 1.0, 2.5]
    assert kept["camera_error_correlation"] == np.eye(3).tolist()
    trains_the_heads = dataclasses.replace(small_config(tmp_path / "run", detection=True), steps=6)
    train_contact(trains_the_heads, contact_sequences, resume=True, progress=False, max_steps=2)
    assert "not kept" in capsys.readouterr().out
    assert "camera_spread_scale" not in torch.load(path, weights_only=False)


def test_a_log_written_with_fewer_columns_is_widened(tmp_path):
    from heightnet.contact_train import _CsvLog

    path = tmp_path / "curve.csv"
    path.write_text("step,images\n250,2000\n")
    log = _CsvLog(path, None)
    log.write({"step": 500, "images": 4000, "det_precision": 0.5})
    log.close()
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows == [{"step": "250", "images": "2000", "det_precision": ""},
                    {"step": "500", "images": "4000", "det_precision": "0.5"}]


def test_detection_targets_mark_each_mover_at_its_box_centre(contact_sequences):
    from heightnet.contact_model import DETECTION_STRIDE
    from stages.centre_detections import centre_detections

    sampling = ContactSampling(crop_probability=0.5, detection=True)
    dataset = ContactPairDataset(contact_sequences, 64, 48, sampling, seed=1)
    total = 0
    for item in range(len(dataset)):
        sample = dataset[item]
        for frame in range(2):
            centre = sample["det_centre"][frame]
            assert centre.shape == (3, 12, 16)
            instances = np.unique(sample["instance"][frame, 0])
            peaks = int((centre == 1).sum())
            assert peaks <= len(instances[instances > 0])
            total += peaks
            assert sample["det_box_mask"][frame].sum() == pytest.approx(peaks)   # one per object
            assert sample["det_ignore"][frame].shape == (1, 12, 16)
            assert not (sample["det_ignore"][frame][0] * (centre == 1).any(axis=0)).any()
            # The targets, read as network outputs, decode to boxes around mover pixels.
            logit = np.log(np.clip(centre, 1e-6, 1 - 1e-6) / np.clip(1 - centre, 1e-6, 1))
            box = sample["det_box"][frame].copy()
            box[2:] = np.exp(box[2:]) * 16.0
            found = centre_detections(logit, box, DETECTION_STRIDE, threshold=0.99)
            assert len(found) == peaks
            for x0, y0, x1, y1 in found.boxes:
                rows = slice(int(max(y0, 0)), int(np.ceil(y1)))
                inside = sample["instance"][frame, 0, rows, int(max(x0, 0)):int(np.ceil(x1))]
                assert (inside > 0).any()
    assert total >= len(dataset)


def test_whole_boxes_span_the_hidden_parts_of_objects_in_view_cut_to_the_window():
    from heightnet.detection_targets import window_boxes
    from synth.dataset import CLASS_NAMES

    instance = np.zeros((40, 60), np.uint16)
    instance[10:20, 5:11] = 1       # a walker's upper half; his legs behind a car
    instance[5:25, 30:36] = 2       # a walker a quarter in view: boxed by what is seen
    instance[0:8, 50:56] = 3        # a walker cut by the frame's top: so is his whole box
    semantic = np.where(instance > 0, CLASS_NAMES.index("pedestrian"), 0).astype(np.uint8)
    whole = {1: (5.0, 10.0, 11.0, 40.0, 0.5), 2: (30.0, 5.0, 36.0, 45.0, 0.25), 3: (50.0, -12.0, 56.0, 8.0, 0.4)}

    def extents(boxes):
        return [(b.x0, b.y0, b.x1, b.y1) for b in boxes]

    assert extents(window_boxes(instance, semantic, 1.0, 1.0, False, 60)) == [
        (5, 10, 11, 20), (30, 5, 36, 25), (50, 0, 56, 8)]
    assert extents(window_boxes(instance, semantic, 1.0, 1.0, False, 60, whole)) == [
        (5, 10, 11, 40), (30, 5, 36, 25), (50, 0, 56, 8)]
    # The frame seen through a window from (2, 4) to (60, 36), scaled x2 and mirrored: the first
    # walker's whole box is cut where the window ends (row 36 of the frame).
    boxes = window_boxes(instance[4:36, 2:60], semantic[4:36, 2:60], 2.0, 2.0, True, 116, whole, (2, 4))
    assert extents(boxes)[:2] == [(116 - 18, 12, 116 - 6, 64), (116 - 68, 2, 116 - 56, 42)]


def test_heightpipe_export_writes_a_v2_model_and_says_so(contact_sequences, tmp_path, capsys):
    from pipeline.cli import main

    train_contact(small_config(tmp_path / "run"), contact_sequences, progress=False, max_steps=1)
    out = tmp_path / "v2.onnx"
    assert main(["export", "--checkpoint", str(tmp_path / "run" / "checkpoint.pt"), "--out", str(out)]) == 0
    assert out.is_file() and "HeightNet v2" in capsys.readouterr().out
    assert main(["export", "--checkpoint", str(tmp_path / "none.pt"), "--out", str(out)]) == 2
    assert "no HeightNet v2 state" in capsys.readouterr().err


@pytest.mark.parametrize("step, expected", [(0, 1e-3 / 200), (199, 1e-3), (999, 1e-3),
                                            (1000, 3e-4), (4999, 3e-4), (5000, 9e-5)])
def test_learning_rate_warms_up_then_steps_down_at_the_drops(step, expected):
    config = TrainV2Config(lr=1e-3, lr_drops=[1000, 5000], lr_drop_factor=0.3)
    assert learning_rate(step, config) == pytest.approx(expected)


def test_parked_vehicles_are_ignored_cells_never_centres():
    """Parked vehicles have no instance (no box to ask for): the cells over them and one around
    are ignored, except where a mover's centre falls."""
    from heightnet.contact_model import DETECTION_STRIDE
    from heightnet.detection_targets import Box, detection_targets, ignored_cells

    parked = np.zeros((48, 64), bool)
    parked[20:28, 40:56] = True              # cells 5-6 (rows) x 10-13 (columns)
    ignore = ignored_cells(parked)
    assert ignore.shape == (1, 48 // DETECTION_STRIDE, 64 // DETECTION_STRIDE)
    rows, cols = np.nonzero(ignore[0])
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (4, 7, 9, 14)
    mover = Box(0, 36.0, 16.0, 44.0, 32.0)  # centre (40, 24): cell (6, 10), inside the ignored area
    targets = detection_targets([mover], 64, 48, ignore)
    assert targets["centre"][0, 6, 10] == 1.0 and targets["ignore"][0, 6, 10] == 0.0
    assert targets["ignore"].sum() == ignore.sum() - 1
    assert detection_targets([mover], 64, 48)["ignore"].sum() == 0


def test_box_targets_cover_the_cells_around_each_centre_and_point_to_its_box():
    """Wherever the peak lands near an object, the box read there is that object's: every
    weighted cell decodes to its box; each object weighs one, half at its centre; where a car's
    and a person's cells meet, the person keeps its own, and no object takes another's centre."""
    from heightnet.contact_model import BOX_UNIT_PX, DETECTION_STRIDE
    from heightnet.detection_targets import CENTRE_BOX_SHARE, Box, detection_targets

    car = Box(2, 0.0, 0.0, 64.0, 48.0)        # centre (32, 24): cell (row 6, column 8)
    person = Box(0, 40.0, 12.0, 48.0, 44.0)   # centre (44, 28): cell (7, 11)
    neighbour = Box(0, 44.0, 12.0, 52.0, 44.0)   # centre (48, 28): cell (7, 12)
    targets = detection_targets([car, person, neighbour], 96, 48)
    mask, box = targets["box_mask"][0], targets["box"]
    assert mask[6, 8] >= CENTRE_BOX_SHARE and mask[7, 11] >= CENTRE_BOX_SHARE and mask[7, 12] >= CENTRE_BOX_SHARE
    assert mask.sum() == pytest.approx(3.0)
    rows, cols = np.nonzero(mask)
    cx = (cols + 0.5) * DETECTION_STRIDE + box[0, rows, cols]
    cy = (rows + 0.5) * DETECTION_STRIDE + box[1, rows, cols]
    width = BOX_UNIT_PX * np.exp(box[2, rows, cols])
    decoded = {(round(float(x)), round(float(y)), round(float(w))) for x, y, w in zip(cx, cy, width)}
    assert decoded == {(32, 24, 64), (44, 28, 8), (48, 28, 8)}
    owner = {(int(r), int(c)): (round(float(x)), round(float(w))) for r, c, x, w in zip(rows, cols, cx, width)}
    assert owner[(6, 10)] == (44, 8)          # the car's Gaussian reaches it; the person wins
    assert owner[(6, 9)] == (32, 64) and (6, 7) in owner and (5, 8) in owner
    assert owner[(7, 12)] == (48, 8) and owner[(7, 11)] == (44, 8)   # centres are their own
    assert len(owner) > 3 * 5


def test_the_big_object_head_is_taught_big_objects_ignores_the_band_below_and_calls_small_ones_background():
    """At 1/16: a 120 px van is a centre with its box; a 56 px walker (between ``BIG_IGNORE_PX``
    and ``BIG_MIN_PX``) is neither asked for nor held against the head; a 30 px walker and a parked
    car's cells are background and ignored respectively, as for the small head."""
    from heightnet.contact_model import BIG_STRIDE, BOX_UNIT_PX
    from heightnet.detection_targets import BIG_IGNORE_PX, BIG_MIN_PX, Box, big_object_targets

    van = Box(2, 100.0, 60.0, 220.0, 180.0)      # centre (160, 120): cell (7, 10)
    band = Box(0, 250.0, 100.0, 270.0, 156.0)     # 56 px: centre (260, 128), cell (8, 16)
    small = Box(0, 20.0, 20.0, 30.0, 50.0)        # 30 px: cell (2, 1)
    assert BIG_IGNORE_PX <= 56 < BIG_MIN_PX <= 120 and 30 < BIG_IGNORE_PX
    parked = np.zeros((240, 320), bool)
    parked[200:230, 20:60] = True                 # cells (12-14) x (1-3)
    t = big_object_targets([van, band, small], 320, 240, parked)
    assert t["centre"].shape == (3, 240 // BIG_STRIDE, 320 // BIG_STRIDE)
    assert t["centre"][2, 7, 10] == 1.0 and (t["centre"] == 1.0).sum() == 1
    assert t["centre"][0].max() == 0.0            # neither walker is asked for
    assert t["ignore"][0, 8, 16] == 1.0 and t["ignore"][0, 1, 2] == 0.0
    assert t["ignore"][0, 12:15, 1:4].all() and t["ignore"][0, 7, 10] == 0.0
    assert np.allclose(t["box"][:, 7, 10], [160 - 10.5 * BIG_STRIDE, 120 - 7.5 * BIG_STRIDE,
                                            math.log(120 / BOX_UNIT_PX), math.log(120 / BOX_UNIT_PX)])
    assert math.isclose(float(t["box_mask"].sum()), 1.0, rel_tol=1e-5)


def test_a_centre_core_marks_big_objects_over_several_cells_and_small_ones_at_one():
    """With ``core``, a van 100 x 160 px is a centre over a block of cells round its centre cell,
    all its own (their boxes decode to the van), never ignored; a walker 10 x 30 px stays one
    cell; without ``core`` the van is one cell too. Cells of 2 px (the half-resolution head)."""
    from heightnet.detection_targets import Box, detection_targets

    van = Box(2, 20.0, 20.0, 120.0, 180.0)
    walker = Box(0, 200.0, 100.0, 210.0, 130.0)
    ignore = np.ones((1, 240 // 2, 320 // 2), np.float32)
    cored = detection_targets([van, walker], 320, 240, ignore, 2, core=0.9)
    plain = detection_targets([van, walker], 320, 240, None, 2)
    assert (plain["centre"] == 1).sum() == 2
    van_cells = np.argwhere(cored["centre"][2] == 1)
    assert 10 <= len(van_cells) <= 40 and (cored["centre"][0] == 1).sum() == 1
    rows, cols = van_cells[:, 0], van_cells[:, 1]
    cx = (cols + 0.5) * 2 + cored["box"][0, rows, cols]
    assert np.allclose(cx, 70.0, atol=1e-3) and (cored["box_mask"][0, rows, cols] > 0).all()
    assert (cored["ignore"][0, rows, cols] == 0).all()


def test_the_detection_head_gets_its_own_learning_rate_from_its_step_on():
    from heightnet.contact_train import group_learning_rates

    config = TrainV2Config(lr=1e-3, lr_drops=[1000], lr_drop_factor=0.1, detection_lr_factor=10.0,
                           detection_lr_from=2000)
    assert group_learning_rates(1500, config) == pytest.approx([1e-4, 1e-4])
    assert group_learning_rates(2000, config) == pytest.approx([1e-4, 1e-3])


def test_a_state_saved_with_one_optimiser_group_resumes_with_the_head_in_its_own(tmp_path):
    """Checkpoints from before the head's group hold one group in parameter order: each Adam
    moment must land on its own parameter again."""
    from heightnet.contact_train import parameter_groups, save_state

    config = small_config(tmp_path / "run", detection=True)
    net = ContactNet(architecture_of(config))
    old = torch.optim.AdamW(net.parameters(), lr=1e-3)
    image = torch.rand(2, 3, config.input_height, config.input_width)
    sum(o.square().mean() for o in net(image)).backward()
    old.step()
    save_state(tmp_path / "state.pt", net, old, 1, 2, config)
    before = {name: old.state[p]["exp_avg"].clone() for name, p in net.named_parameters()}

    fresh = ContactNet(architecture_of(config))
    grouped = torch.optim.AdamW(parameter_groups(fresh), lr=1e-3)
    assert len(grouped.param_groups) == 2
    load_state(tmp_path / "state.pt", fresh, grouped, config)
    for name, p in fresh.named_parameters():
        assert torch.allclose(grouped.state[p]["exp_avg"], before[name], atol=1e-3, rtol=1e-2), name
    assert any(name.startswith("detection_head.") for name, _ in fresh.named_parameters())


def test_a_missing_v2_data_folder_is_an_error_unless_the_data_command_writes_it(tmp_path, monkeypatch):
    """`heightpipe train --data A,B` (v2) reads every folder named; a missing one is one clear
    error, and the configured data command (which writes its own --out) is not run for it: it
    rendered the configured data into another folder than the one named."""
    import argparse

    from core.config import load_config
    from core.errors import ConfigError
    from heightnet import cli_train

    monkeypatch.chdir(tmp_path)
    config = load_config(overrides=["train.formulation=contact"])
    parser = argparse.ArgumentParser()
    cli_train.add_arguments(parser)
    args = parser.parse_args(["--data", "data/mistyped", "--out", "run", "--no-progress"])
    with pytest.raises(ConfigError, match="no synth dataset at data/mistyped"):
        cli_train.train_v2(args, config)
    assert not (tmp_path / "data").exists()
    assert cli_train._writes_to(config.train_v2.data_command) == Path(config.train_v2.data)
    assert cli_train._writes_to("heightpipe synth --sequences 3") is None


@pytest.mark.parametrize("key", ["data", "test_data"])
def test_a_v2_data_list_naming_no_folder_says_which_key(tmp_path, monkeypatch, key):
    import argparse
    from types import SimpleNamespace

    from core.config import load_config
    from core.errors import ConfigError
    from heightnet import cli_train

    monkeypatch.chdir(tmp_path)
    config = load_config(overrides=["train.formulation=contact", f"train_v2.{key}= , "])
    parser = argparse.ArgumentParser()
    cli_train.add_arguments(parser)
    args = parser.parse_args(["--out", "run", "--no-progress"])
    if key == "test_data":      # a training set that is there, so the held-out list is read
        monkeypatch.setattr(cli_train.Path, "is_file", lambda self: True)
        monkeypatch.setattr("synth.dataset.list_sequences", lambda folder, split: [SimpleNamespace(name="s")])
        monkeypatch.setattr("heightnet.contact_data.build_contact_cache", lambda seqs, *a, **k: list(seqs))
    with pytest.raises(ConfigError, match=f"train_v2.{key} names no dataset"):
        cli_train.train_v2(args, config)


def test_v2_data_folders_are_read_in_turn_and_too_many_files_is_one_clear_error(tmp_path, monkeypatch):
    """`--data A,B`: A's sequences then B's, the first ``train_v2.sequences`` over both, each
    folder cached in its own place; a machine out of file handles (every cached sequence
    memory-maps its arrays) is one line saying what to do, not a traceback."""
    import argparse
    import errno
    from types import SimpleNamespace

    import heightnet.contact_data
    import heightnet.contact_train
    import synth.dataset
    from core.config import load_config
    from core.errors import ConfigError
    from heightnet import cli_train

    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "manifest.json").write_text("{}")
    monkeypatch.setattr(synth.dataset, "list_sequences", lambda folder, split: [
        SimpleNamespace(name=f"{Path(folder).name}{i}") for i in (1, 0)])
    cached = []
    monkeypatch.setattr(heightnet.contact_data, "build_contact_cache",
                        lambda sequences, cache_dir, **kw: cached.append((cache_dir, [s.name for s in sequences]))
                        or [s.name for s in sequences])
    trained = []
    monkeypatch.setattr(heightnet.contact_train, "train_contact",
                        lambda config, train_set, held_out, **kw: trained.append(train_set) or {"step": 0, "images": 0})
    config = load_config(overrides=["train.formulation=contact", "train_v2.sequences=3", "train_v2.test_data="])
    parser = argparse.ArgumentParser()
    cli_train.add_arguments(parser)
    args = parser.parse_args(["--data", f"{tmp_path / 'a'}, {tmp_path / 'b'}", "--out", str(tmp_path / "run"),
                              "--no-progress"])
    assert cli_train.train_v2(args, config) == 0
    assert trained == [["a0", "a1", "b0"]]
    assert cached == [(tmp_path / "a" / ".contact_cache", ["a0", "a1"]),
                      (tmp_path / "b" / ".contact_cache", ["b0"])]

    def out_of_files(sequences, cache_dir, **kw):
        raise OSError(errno.EMFILE, "Too many open files")

    monkeypatch.setattr(heightnet.contact_data, "build_contact_cache", out_of_files)
    with pytest.raises(ConfigError, match="more files than this machine allows"):
        cli_train.train_v2(args, config)


def test_targets_at_half_resolution_ask_for_the_same_boxes_on_twice_the_cells():
    """A fine head (``detection_fine``) is trained at 1/2: each object's centre is the 2-pixel
    cell under its box centre, its Gaussian as wide in input pixels, its boxes decode to the same
    box, and parked vehicles are ignored as far around (in pixels) as at 1/4."""
    from heightnet.contact_model import BOX_UNIT_PX
    from heightnet.detection_targets import Box, detection_targets, ignored_cells

    person = Box(0, 41.0, 12.0, 49.0, 44.0)   # centre (45, 28): cell (7, 11) at 1/4, (14, 22) at 1/2
    quarter = detection_targets([person], 96, 48)
    half = detection_targets([person], 96, 48, stride=2)
    assert half["centre"].shape == (3, 24, 48) and quarter["centre"].shape == (3, 12, 24)
    assert quarter["centre"][0, 7, 11] == 1.0 and half["centre"][0, 14, 22] == 1.0
    assert (half["centre"] == 1.0).sum() == 1
    # Equal width in pixels: the Gaussian's share of cells above one half is about four times.
    assert 3 <= (half["centre"][0] > 0.5).sum() / (quarter["centre"][0] > 0.5).sum() <= 5
    mask, box = half["box_mask"][0], half["box"]
    assert mask.sum() == pytest.approx(1.0)
    rows, cols = np.nonzero(mask)
    assert {(int(r), int(c)) for r, c in zip(rows, cols)} >= {(r, c) for r in range(12, 17) for c in range(20, 25)}
    cx = (cols + 0.5) * 2 + box[0, rows, cols]
    cy = (rows + 0.5) * 2 + box[1, rows, cols]
    assert np.allclose(cx, 45.0) and np.allclose(cy, 28.0)
    assert np.allclose(BOX_UNIT_PX * np.exp(box[2:, rows, cols]), [[8.0], [32.0]])
    parked = np.zeros((48, 64), bool)
    parked[20:28, 40:56] = True
    ignore = ignored_cells(parked, stride=2)
    rows, cols = np.nonzero(ignore[0])
    assert ignore.shape == (1, 24, 32)
    assert (rows.min() * 2, (rows.max() + 1) * 2, cols.min() * 2, (cols.max() + 1) * 2) == (16, 32, 36, 60)
