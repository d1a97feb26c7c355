"""v2's camera heads on fresh cameras: errors, the honesty of their spread, a refit
(heightnet/camera_fresh.py)."""

import numpy as np
import pytest
import torch
from torch import nn

from fake_synth import fake_sequences
from heightnet.camera_fresh import (CameraExamples, RefitSettings, camera_errors, camera_examples, error_correlation,
                                    held_back_rows, horizon, main, refit_head, spread_scale, with_spread_scale)
from heightnet.contact_model import ContactArchitecture, ContactNet

ARCH = ContactArchitecture(widths=(8, 8, 16, 16), context=(2,), position=True)


def test_each_camera_gives_its_frame_and_the_mirror_image_with_the_roll_negated():
    torch.manual_seed(0)
    net = ContactNet(ARCH)
    examples = camera_examples(net, fake_sequences(count=2, frames=1), 64, 48)
    assert examples.features.shape == (4, 2 * ARCH.widths[-1])
    assert examples.cameras.tolist() == [0, 0, 1, 1]
    assert examples.targets[1, 1] == pytest.approx(-examples.targets[0, 1])
    assert examples.targets[1, [0, 2]] == pytest.approx(examples.targets[0, [0, 2]])
    assert examples.targets[0, 0] == pytest.approx(np.radians(25.0), abs=1e-5)   # fake cameras look 25 deg down
    # The features are the pooled bottleneck the network's own heads read.
    with torch.no_grad():
        image = torch.rand(1, 3, 48, 64)
        _, _, camera = net(image)[:3]
        _, bottleneck = net.encode(image)
        pooled = torch.cat([bottleneck.mean((2, 3)), bottleneck.amax((2, 3))], 1)
        assert torch.allclose(net.camera_head(pooled), camera)


def test_held_back_rows_take_whole_cameras_by_seed():
    cameras = np.repeat(np.arange(12), 2)
    rows = held_back_rows(cameras, 1 / 6, seed=3)
    assert rows.sum() == 4 and set(np.unique(cameras[rows])) == set(cameras[rows][::2])
    assert all(rows[cameras == c].all() or not rows[cameras == c].any() for c in range(12))
    assert (held_back_rows(cameras, 1 / 6, seed=3) == rows).all()


def _linear_cameras(n: int, seed: int) -> CameraExamples:
    """Features that carry the camera linearly: a head can learn it."""
    rng = np.random.default_rng(seed)
    features = rng.normal(size=(n, 8)).astype(np.float32)
    targets = np.stack([0.45 + 0.1 * features[:, 0], 0.02 * features[:, 1], 0.1 * features[:, 2]], 1)
    return CameraExamples(features, targets.astype(np.float32), np.arange(n))


def test_refitting_learns_what_the_features_carry_and_keeps_the_best_epoch():
    torch.manual_seed(0)
    head = nn.Sequential(nn.Linear(8, 32), nn.ReLU(), nn.Linear(32, 6))
    fit, check = _linear_cameras(600, 0), _linear_cameras(100, 1)
    before = camera_errors(head(torch.from_numpy(check.features)).detach().numpy(), check.targets)
    refitted, epoch, history = refit_head(head, fit, check, RefitSettings(epochs=30))
    after = camera_errors(refitted(torch.from_numpy(check.features)).detach().numpy(), check.targets)
    assert epoch > 0 and history[epoch] == min(history)
    assert after["horizon_mean_pct"] == pytest.approx(history[epoch], rel=1e-5)
    assert after["horizon_mean_pct"] < 0.25 * before["horizon_mean_pct"]
    assert after["pitch_deg"] < 0.1 * before["pitch_deg"]
    # The head given is left as it was.
    assert camera_errors(head(torch.from_numpy(check.features)).detach().numpy(),
                         check.targets)["horizon_mean_pct"] == pytest.approx(before["horizon_mean_pct"])


def test_no_epoch_better_than_the_start_keeps_the_head_as_given():
    head = nn.Sequential(nn.Linear(8, 32), nn.ReLU(), nn.Linear(32, 6))
    check = _linear_cameras(50, 1)
    refitted, epoch, history = refit_head(head, _linear_cameras(50, 0), check, RefitSettings(epochs=0))
    assert epoch == 0 and len(history) == 1
    for a, b in zip(refitted.state_dict().values(), head.state_dict().values()):
        assert torch.equal(a, b)


def test_horizon_is_focal_length_times_tan_pitch():
    values = np.array([[np.radians(30), 0.0, np.log(1.2)]])
    assert horizon(values)[0] == pytest.approx(1.2 * np.tan(np.radians(30)))


def test_the_spread_scale_is_the_error_in_units_of_the_reported_spread():
    rng = np.random.default_rng(0)
    targets = rng.normal(size=(4000, 3)).astype(np.float32)
    log_var = np.log(np.array([0.02, 0.01, 0.1]) ** 2)            # reported std 0.02, 0.01, 0.1
    errors = rng.normal(size=(4000, 3)) * np.array([0.04, 0.01, 0.3])   # 2x, 1x, 3x that
    outputs = np.concatenate([targets + errors, np.tile(log_var, (4000, 1))], 1)
    assert spread_scale(outputs, targets) == pytest.approx([2.0, 1.0, 3.0], rel=0.05)


def test_the_error_correlation_is_that_of_the_scaled_errors():
    rng = np.random.default_rng(0)
    targets = rng.normal(size=(6000, 3)).astype(np.float32)
    log_var = np.log(np.array([0.02, 0.01, 0.1]) ** 2)
    shared = rng.normal(size=6000)
    errors = np.column_stack([0.04 * (0.9 * shared + 0.436 * rng.normal(size=6000)), 0.01 * rng.normal(size=6000),
                              -0.3 * shared])                      # pitch and focal: correlation -0.9
    outputs = np.concatenate([targets + errors, np.tile(log_var, (6000, 1))], 1)
    correlation = error_correlation(outputs, targets)
    assert np.diag(correlation) == pytest.approx([1, 1, 1])
    assert correlation[0, 2] == pytest.approx(-0.9, abs=0.02) and correlation[0, 2] == correlation[2, 0]
    assert abs(correlation[0, 1]) < 0.05 and abs(correlation[1, 2]) < 0.05


def test_an_exported_model_carries_the_spread_scale_to_the_run(tmp_path):
    """state --write--> export metadata --> HeightNetModel --> the heads' spread a run reports."""
    from core.packets import CameraInfo
    from heightnet.contact_export import export_contact
    from heightnet.contact_train import save_state
    from core.config import TrainV2Config
    from stages.contact_heights import ContactHeights
    from stages.heightnet_model import HeightNetModel

    torch.manual_seed(0)
    net = ContactNet(ARCH).eval()
    path = tmp_path / "checkpoint.pt"
    save_state(path, net, torch.optim.Adam(net.parameters()), step=1, images=2,
               config=TrainV2Config(out=str(tmp_path), input_width=64, input_height=48))
    export_contact(path, tmp_path / "plain.onnx")
    state = torch.load(path, weights_only=False)
    correlation = np.array([[1.0, 0.1, -0.8], [0.1, 1.0, 0.0], [-0.8, 0.0, 1.0]])
    torch.save(with_spread_scale(state, np.array([2.5, 1.0, 2.0]), {"cameras": 3}, correlation), path)
    export_contact(path, tmp_path / "scaled.onnx")
    plain, scaled = HeightNetModel(tmp_path / "plain.onnx"), HeightNetModel(tmp_path / "scaled.onnx")
    assert plain.info.camera_spread_scale == (1.0, 1.0, 1.0)
    assert scaled.info.camera_spread_scale == (2.5, 1.0, 2.0)
    assert np.array(plain.info.camera_error_correlation) == pytest.approx(np.eye(3))
    assert np.array(scaled.info.camera_error_correlation) == pytest.approx(correlation)
    image = np.zeros((48, 64, 3), np.uint8)
    only_height = CameraInfo(64, 48, height_m=5.0, source="camera-height")
    widened = ContactHeights(spread_scale=scaled.info.camera_spread_scale)
    _, wide = widened.decode(scaled.run(image), only_height, (64, 48))
    _, narrow = ContactHeights().decode(plain.run(image), only_height, (64, 48))
    assert wide.pitch_std_deg == pytest.approx(2.5 * narrow.pitch_std_deg, rel=1e-4)
    assert wide.roll_std_deg == pytest.approx(narrow.roll_std_deg, rel=1e-4)
    assert np.log1p(wide.focal_std_pct / 100) == pytest.approx(2.0 * np.log1p(narrow.focal_std_pct / 100), rel=1e-4)


def test_a_missing_state_or_dataset_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["--data", str(tmp_path), "--state", str(tmp_path / "none.pt")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    (tmp_path / "state.pt").write_bytes(b"")
    assert main(["--data", str(tmp_path), "--state", str(tmp_path / "state.pt")]) == 2
    assert "not a generator dataset" in capsys.readouterr().err


def test_the_command_measures_fresh_cameras_and_writes_the_scale_into_the_state(tmp_path, capsys):
    from core.config import TrainV2Config
    from heightnet.contact_train import save_state
    from pipeline.cli import main as cli_main

    assert cli_main(["synth", "--out", str(tmp_path / "fresh"), "--sequences", "3", "--frames", "1",
                     "--size", "96x72", "--seed", "5", "--split", "train", "--workers", "1", "--no-shadows",
                     "--no-post", "--no-progress"]) == 0
    torch.manual_seed(0)
    net = ContactNet(ARCH)
    state = tmp_path / "checkpoint.pt"
    save_state(state, net, torch.optim.Adam(net.parameters()), step=1, images=2,
               config=TrainV2Config(out=str(tmp_path), input_width=64, input_height=48))
    capsys.readouterr()
    assert main(["--data", str(tmp_path / "fresh"), "--state", str(state), "--write", "--epochs", "2",
                 "--threads", "1", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "refit on 2 fresh cameras, 1 held back" in printed and "| fresh, all 3 (the scale) |" in printed
    written = torch.load(state, weights_only=False)
    assert len(written["camera_spread_scale"]) == 3 and all(v > 0 for v in written["camera_spread_scale"])
    assert np.diag(written["camera_error_correlation"]) == pytest.approx([1, 1, 1])
    assert written["camera_spread"]["cameras"] == 3 and written["camera_spread"]["datasets"][0]["seed"] == 5
    for name, value in net.state_dict().items():   # the weights are left as they were
        assert torch.equal(written["ema"][name], value)
