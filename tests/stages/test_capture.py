import cv2
import numpy as np
import pytest

from media import SHARED_REAL, mjpeg_server, write_truncated_avi
from core.config import CaptureConfig
from core.errors import ConfigError, SourceError
from stages.capture import StreamSource, evenly_spaced, open_source, processing_size

TRAFFIC = SHARED_REAL / "traffic_bridge" / "car_traffic_small.mp4"


def test_video_file_reads_all_frames_with_container_times(box_video):
    source = open_source(str(box_video), CaptureConfig())
    frames = list(source.frames())
    assert [f.index for f in frames] == list(range(30))
    assert frames[1].time_s == pytest.approx(0.1, abs=1e-3)
    assert source.stats.decoded == 30 and source.stats.failed == 0


def test_stride_keeps_source_indices_and_times(box_video):
    source = open_source(str(box_video), CaptureConfig(stride=4, max_frames=5))
    frames = list(source.frames())
    assert [f.index for f in frames] == [0, 4, 8, 12, 16]
    assert frames[2].time_s == pytest.approx(0.8, abs=1e-3)


def test_background_sample_reads_ahead_without_disturbing_the_run(box_video):
    """Frames spread over the clip's first seconds (box video: 30 frames at 10 fps)."""
    source = open_source(str(box_video), CaptureConfig())
    sample = source.background_sample(5, span_s=2.0)              # over frames 0..19
    assert len(sample) == 5 and sample[0].shape == (120, 160, 3)
    reference = [f.image for f in open_source(str(box_video), CaptureConfig()).frames()]
    for image, index in zip(sample, evenly_spaced(20, 5)):
        assert np.abs(image.astype(int) - reference[index]).mean() < 1.0
    assert len(list(source.frames())) == 30                      # the run's own reader starts at frame 0
    assert source.background_sample(0, span_s=2.0) == []


def test_opening_samples_read_two_spreads_in_one_pass(box_video, monkeypatch):
    """A run told only the camera height reads its camera from more early frames than its
    background is primed with: both come from one look-ahead pass, each as if read alone."""
    source = open_source(str(box_video), CaptureConfig())
    alone = [source.background_sample(3, span_s=2.0), source.background_sample(6, span_s=3.0)]
    passes = []
    reader = source._images_at
    monkeypatch.setattr(source, "_images_at", lambda indices: passes.append(indices) or reader(indices))
    together = source.opening_samples((3, 2.0), (6, 3.0), (0, 1.0))
    assert len(passes) == 1
    assert [len(group) for group in together] == [3, 6, 0]
    for mine, theirs in zip(together, alone):
        assert all(np.array_equal(a, b) for a, b in zip(mine, theirs))


def test_spread_sample_reads_frames_over_the_whole_clip_one_at_a_time(box_video):
    """``heightpipe calibrate --camera-height`` on a long recording: a few frames from all of it."""
    source = open_source(str(box_video), CaptureConfig())
    sample = source.spread_sample(4)
    assert not isinstance(sample, list), "a generator: a long recording's frames are not held at once"
    reference = [f.image for f in open_source(str(box_video), CaptureConfig()).frames()]
    images = list(sample)
    assert len(images) == 4
    for image, index in zip(images, [0, 10, 19, 29]):             # evenly_spaced(30, 4): first and last
        assert np.abs(image.astype(int) - reference[index]).mean() < 1.0
    assert len(list(source.frames())) == 30                      # the run's own reader is untouched
    assert list(source.spread_sample(0)) == []


def test_spread_sample_of_a_folder_is_fitted_to_the_run_size(tmp_path):
    for i in range(6):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((96, 128, 3), 40 * i, np.uint8))
    images = list(open_source(str(tmp_path), CaptureConfig(max_width=64)).spread_sample(3))
    assert [image.shape for image in images] == [(48, 64, 3)] * 3
    assert [int(image[0, 0, 0]) for image in images] == [0, 80, 200]   # frames 0, 2 and 5


def test_evenly_spaced():
    assert evenly_spaced(20, 5) == [0, 5, 10, 14, 19]
    assert evenly_spaced(3, 10) == [0, 1, 2]
    assert evenly_spaced(0, 4) == [] and evenly_spaced(9, 0) == []


@pytest.mark.skipif(not TRAFFIC.exists(), reason="shared real clips not present")
def test_real_clip_decodes_917_frames_and_reports_the_header_mismatch():
    source = open_source(str(TRAFFIC), CaptureConfig())
    count = sum(1 for _ in source.frames())
    assert count == 917
    assert source.stats.expected == 922
    assert "917 frames decoded" in source.stats.summary()


def test_missing_file():
    with pytest.raises(SourceError, match="no such file"):
        open_source("does/not/exist.mp4", CaptureConfig())


def test_file_that_is_not_a_video(tmp_path):
    path = tmp_path / "notes.mp4"
    path.write_text("this is text, not a video\n" * 100)
    with pytest.raises(SourceError, match="not a readable video"):
        open_source(str(path), CaptureConfig())


def test_truncated_video_processes_what_decodes(tmp_path):
    cut = write_truncated_avi(tmp_path / "cut.avi", frames=40)
    source = open_source(str(cut), CaptureConfig())
    frames = list(source.frames())
    assert 5 < len(frames) < 40
    assert source.stats.decoded == len(frames)


def test_image_folder_counts_undecodable_images(tmp_path):
    for i in range(5):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((24, 32, 3), i * 40, np.uint8))
    (tmp_path / "002.png").write_bytes(b"broken")
    source = open_source(str(tmp_path), CaptureConfig())
    frames = list(source.frames())
    assert [f.index for f in frames] == [0, 1, 3, 4]
    assert source.stats.failed == 1
    glob_frames = list(open_source(str(tmp_path / "00[34].png"), CaptureConfig()).frames())
    assert len(glob_frames) == 2


def test_frames_of_another_size_are_scaled_or_left_out_by_their_aspect_ratio(tmp_path):
    sizes = [(64, 48), (32, 24), (128, 96), (48, 48), (64, 48)]  # 4:3, 4:3, 4:3, 1:1, 4:3
    for i, (w, h) in enumerate(sizes):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((h, w, 3), 40 * i, np.uint8))
    source = open_source(str(tmp_path), CaptureConfig())
    frames = list(source.frames())
    assert [f.index for f in frames] == [0, 1, 2, 4]
    assert {f.image.shape for f in frames} == {(48, 64, 3)}
    assert [int(f.image.mean()) for f in frames] == [0, 40, 80, 160], "scaled, not replaced"
    assert (source.stats.rescaled, source.stats.wrong_shape, source.stats.failed) == (2, 1, 0)
    text = source.stats.summary()
    assert "2 at another resolution (scaled)" in text and "1 of another aspect ratio (not processed)" in text
    assert "frame 1 was the first at 32x24 (the run's frames are 64x48)" in text
    assert "frame 3 was the first at 48x48" in text


@pytest.mark.parametrize("size, max_width, expected", [
    ((1920, 1080), 960, (960, 540)),    # whole factor 2
    ((1280, 720), 960, (640, 360)),     # 2, not 1.33: whole blocks are cheap and exact
    ((3840, 2160), 960, (960, 540)),    # 4
    ((2560, 1440), 960, (853, 480)),    # 3
    ((960, 540), 960, (960, 540)),      # fits already
    ((640, 360), 960, (640, 360)),
    ((1920, 1080), 0, (1920, 1080)),    # 0: full size
    (None, 960, None),                  # not open yet
])
def test_processing_size_divides_by_the_smallest_whole_factor_that_fits(size, max_width, expected):
    assert processing_size(size, max_width) == expected


def test_frames_wider_than_max_width_are_processed_scaled_and_say_so(tmp_path):
    """The look-ahead too; frames of another size are fitted to the same processed size."""
    sizes = [(128, 96), (128, 96), (256, 192), (64, 48), (96, 96)]
    rng = np.random.default_rng(0)
    originals = []
    for i, (w, h) in enumerate(sizes):
        image = (rng.random((h, w, 3)) * 255).astype(np.uint8)
        originals.append(image)
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), image)
    source = open_source(str(tmp_path), CaptureConfig(max_width=64))
    assert (source.source_size, source.size, source.source_scale) == ((128, 96), (64, 48), (2.0, 2.0))
    frames = list(source.frames())
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert {f.image.shape for f in frames} == {(48, 64, 3)}
    assert {f.source_scale for f in frames} == {(2.0, 2.0)}
    block_means = originals[0].reshape(48, 2, 64, 2, 3).mean(axis=(1, 3))
    assert np.abs(frames[0].image - block_means).max() <= 1.0, "2x2 blocks averaged"
    assert (source.stats.rescaled, source.stats.wrong_shape) == (2, 1), "the source's own size is not counted"
    assert "128x96 frames processed at 64x48 (capture.max_width = 64" in source.scaling_note()
    assert "the run's frames are 128x96" in source.stats.summary()
    sample = source.background_sample(5, span_s=10.0)
    assert len(sample) == 4 and {image.shape for image in sample} == {(48, 64, 3)}
    assert open_source(str(tmp_path), CaptureConfig(max_width=0)).scaling_note() == ""


def test_a_negative_max_width_is_a_config_error(box_video):
    with pytest.raises(ConfigError, match="capture.max_width"):
        open_source(str(box_video), CaptureConfig(max_width=-1))


def _read_with_one_reconnect(server):
    """Every frame of ``server``'s stream, allowed one reconnect: (source, frames)."""
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/video.mjpg"
        source = open_source(url, CaptureConfig(reconnect_attempts=1, backoff_s=0.01, read_timeout_s=2))
        return source, list(source.frames())
    finally:
        server.shutdown()


def test_a_stream_that_comes_back_at_another_resolution_is_scaled_to_the_first():
    server, connections = mjpeg_server([10, 15], sizes_per_connection=[(64, 48), (128, 96)])
    source, frames = _read_with_one_reconnect(server)
    assert len(connections) == 2 and source.stats.reconnects == 1
    assert len(frames) == 25 and {f.image.shape for f in frames} == {(48, 64, 3)}
    assert source.stats.rescaled == 15


def test_empty_folder_and_unmatched_glob(tmp_path):
    with pytest.raises(SourceError, match="without images"):
        open_source(str(tmp_path), CaptureConfig())
    with pytest.raises(SourceError, match="no images match"):
        open_source(str(tmp_path / "*.png"), CaptureConfig())


class _NeverOpens:
    def isOpened(self):
        return False

    def release(self):
        pass


def test_unreachable_stream_retries_with_backoff_then_fails():
    delays = []
    with pytest.raises(SourceError, match="cannot open stream rtsp://cam/1 after 4 attempts"):
        StreamSource("rtsp://cam/1", CaptureConfig(connect_attempts=4, backoff_s=0.5),
                     opener=lambda url: _NeverOpens(), sleep=delays.append)
    assert delays == [0.5, 1.0, 2.0]


class _OpensButSendsNothing(_NeverOpens):
    def isOpened(self):
        return True

    def read(self):
        return False, None

    def get(self, prop):
        return 0.0


def test_stream_that_opens_but_sends_no_frame_is_one_clear_error():
    with pytest.raises(SourceError, match="opened but sent no frame within 2 s"):
        StreamSource("rtsp://cam/1", CaptureConfig(read_timeout_s=2), opener=lambda url: _OpensButSendsNothing())


def test_stream_knows_its_frame_size_before_the_first_frame_is_asked_for():
    server, _ = mjpeg_server([5])
    try:
        source = open_source(f"http://127.0.0.1:{server.server_address[1]}/video.mjpg",
                             CaptureConfig(reconnect_attempts=0, read_timeout_s=2))
        assert source.size == (64, 48)
        frames = list(source.frames())
    finally:
        server.shutdown()
    assert len(frames) == 5, "the frame read to learn the size is handed out, not lost"
    assert frames[0].image.shape == (48, 64, 3)


def test_unreachable_real_rtsp_url_fails_fast():
    with pytest.raises(SourceError, match="cannot open stream"):
        open_source("rtsp://127.0.0.1:9/none", CaptureConfig(connect_attempts=2, backoff_s=0.01))


def test_stream_that_drops_mid_run_reconnects_and_keeps_recording():
    server, connections = mjpeg_server([20, 30])
    source, frames = _read_with_one_reconnect(server)
    assert len(connections) == 2
    assert source.stats.reconnects == 1
    assert len(frames) == 50
    times = [f.time_s for f in frames]
    assert all(b >= a for a, b in zip(times, times[1:])), "time must not run backwards after a reconnect"
