"""PyAV capture: frames decoded with errors are reported, never passed off as clean."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from damage import damaged_against, decode_all, flip_bits, truncate
from media import REPO_ROOT
from core.config import CaptureConfig
from core.errors import ConfigError, SourceError
from stages.capture import VideoFileSource, open_source
from stages.pyav_capture import DamageTracker, PyAVFileSource

SAMPLE = REPO_ROOT / "recordings" / "sample.mp4"


def test_clean_video_matches_opencv_frame_for_frame():
    pyav = open_source(str(SAMPLE), CaptureConfig())
    opencv = open_source(str(SAMPLE), CaptureConfig(backend="opencv"))
    assert isinstance(pyav, PyAVFileSource) and isinstance(opencv, VideoFileSource)
    ours, theirs = list(pyav.frames()), list(opencv.frames())
    assert [(f.index, round(f.time_s, 3)) for f in ours] == [(f.index, round(f.time_s, 3)) for f in theirs]
    assert len(ours) == 180 and not any(f.damage for f in ours)
    assert pyav.stats.summary() == "180 frames decoded"
    assert pyav.fps == pytest.approx(15.0) and pyav.size == (640, 360)


def test_images_are_pyav_own_conversion_bit_for_bit_with_one_converter_for_the_run():
    """The capture keeps one colour converter for all frames (building one per frame cost 1-2 ms
    a frame): the pixels are still those of ``VideoFrame.to_ndarray(format="bgr24")``."""
    import av
    import numpy as np

    with av.open(str(SAMPLE)) as container:
        theirs = [frame.to_ndarray(format="bgr24") for frame in container.decode(video=0)]
    ours = [frame.image for frame in open_source(str(SAMPLE), CaptureConfig()).frames()]
    assert len(ours) == len(theirs) == 180
    assert all(np.array_equal(a, b) for a, b in zip(ours, theirs))


def test_every_frame_that_differs_from_the_clean_decode_is_reported(tmp_path):
    flipped = tmp_path / "flipped.mp4"
    flipped.write_bytes(flip_bits(SAMPLE.read_bytes(), count=5, seed=1))
    source = open_source(str(flipped), CaptureConfig())
    frames = list(source.frames())
    differing = damaged_against(decode_all(SAMPLE), {f.index: f.image for f in frames})
    reported = {f.index for f in frames if f.damage}
    assert differing and differing <= reported
    assert source.stats.damaged == len(reported)
    assert f"{len(reported)} damaged" in source.stats.summary()
    first = min(reported)
    assert "decoder" in next(f.damage for f in frames if f.index == first)


def test_stride_and_max_frames_keep_source_indices():
    source = open_source(str(SAMPLE), CaptureConfig(stride=3, max_frames=4))
    assert [f.index for f in source.frames()] == [0, 3, 6, 9]
    assert all(f.image.shape == (360, 640, 3) for f in open_source(str(SAMPLE), CaptureConfig(max_frames=2)).frames())


def test_background_sample_skips_nothing_of_the_run():
    source = open_source(str(SAMPLE), CaptureConfig())
    assert len(source.background_sample(5, span_s=30.0)) == 5
    assert len(list(source.frames())) == 180


def test_spread_sample_reads_frames_from_all_of_the_file():
    import numpy as np

    from stages.capture import evenly_spaced

    clean = {f.index: f.image for f in open_source(str(SAMPLE), CaptureConfig(backend="opencv")).frames()}
    images = list(open_source(str(SAMPLE), CaptureConfig()).spread_sample(4))
    assert len(images) == 4
    for image, index in zip(images, evenly_spaced(180, 4)):          # 0, 60, 119, 179
        assert np.abs(image.astype(int) - clean[index]).mean() < 1.0


def test_mp4_cut_before_its_index_is_a_one_line_error_that_says_what_to_do(tmp_path):
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(truncate(SAMPLE.read_bytes(), 0.9))
    with pytest.raises(SourceError, match="without its index .*--reference") as error:
        open_source(str(cut), CaptureConfig())
    assert "\n" not in str(error.value)


def test_unknown_backend():
    with pytest.raises(ConfigError, match="capture.backend"):
        open_source(str(SAMPLE), CaptureConfig(backend="gstreamer"))


def _frame(time, key=False, corrupt=False):
    return SimpleNamespace(time=time, key_frame=key, is_corrupt=corrupt)


@pytest.mark.parametrize("events, expected", [
    # (time s, key frame, corrupt flag, decoder errors) -> (index, damaged?)
    ([(0.0, True, False, []), (0.1, False, False, []), (0.2, False, False, [])],
     [(0, False), (1, False), (2, False)]),
    # a corrupt frame spreads to the frames predicted from it, up to the next clean key frame
    ([(0.0, True, False, []), (0.1, False, True, []), (0.2, False, False, []), (0.3, True, False, []),
      (0.4, False, False, [])],
     [(0, False), (1, True), (2, True), (3, False), (4, False)]),
    # two frames missing: the indices skip them, the next frame is damaged (its reference is gone)
    ([(0.0, True, False, []), (0.1, False, False, []), (0.4, False, False, [])],
     [(0, False), (1, False), (4, True)]),
    # ... unless it is a key frame, which needs no reference
    ([(0.0, True, False, []), (0.3, True, False, []), (0.4, False, False, [])],
     [(0, False), (3, False), (4, False)]),
    # a decoder error counts like a corrupt flag; a time stamp going back is damage too
    ([(0.0, True, False, ["ac-tex damaged"]), (0.1, True, False, []), (0.05, False, False, [])],
     [(0, True), (1, False), (2, True)]),
])
def test_damage_tracker(events, expected):
    tracker = DamageTracker(fps=10.0)
    got = []
    for time, key, corrupt, errors in events:
        frame = tracker.next_frame(_frame(time, key, corrupt), errors).frame
        got.append((frame.index, bool(frame.damage)))
    assert got == expected


@pytest.mark.parametrize("container", ["mp4", "matroska", "avi"])
def test_zeroed_header_is_repaired_and_the_file_reads_as_new(tmp_path, container):
    from damage import zero_header
    from damage_corpus import remux

    clean = remux(SAMPLE, tmp_path / f"clean.{container[:3]}", {"matroska": "mkv"}.get(container, container),
                  max_frames=24)
    damaged = tmp_path / f"damaged.{container[:3]}"
    damaged.write_bytes(zero_header(clean.read_bytes()))
    source = open_source(str(damaged), CaptureConfig())
    frames = {f.index: f.image for f in source.frames()}
    assert len(frames) == 24 and not damaged_against(decode_all(clean), frames)
    assert "repaired" in source.stats.summary()
    assert damaged.read_bytes()[:4] == bytes(4)  # the file itself is left as it was


@pytest.mark.parametrize("codec_source", ["sample", "traffic"])
def test_mp4_cut_at_90_percent_is_salvaged_with_a_reference(tmp_path, codec_source):
    """Must-show 2: at least 80 % of the frames before the cut processed (MPEG-4 part 2 and H.264)."""
    from damage_corpus import TRAFFIC, packet_ends, remux

    if codec_source == "traffic" and not TRAFFIC.exists():
        pytest.skip("shared real clips not present")
    clean = remux(SAMPLE if codec_source == "sample" else TRAFFIC, tmp_path / "clean.mp4", "mp4", max_frames=120)
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(truncate(clean.read_bytes(), 0.9))
    present = sum(end <= cut.stat().st_size for end in packet_ends(clean))
    source = open_source(str(cut), CaptureConfig(reference=str(clean)))
    frames = {f.index: f for f in source.frames()}
    assert len(frames) >= 0.8 * present
    differing = damaged_against(decode_all(clean), {i: f.image for i, f in frames.items()})
    assert differing <= {i for i, f in frames.items() if f.damage}
    assert "salvaged" in source.stats.summary()


def test_salvage_reads_past_deleted_bytes(tmp_path):
    """The chain of NAL lengths breaks at each deleted byte; salvage picks it up again after."""
    from damage import delete_bytes
    from damage_corpus import TRAFFIC, remux

    if not TRAFFIC.exists():
        pytest.skip("shared real clips not present")
    clean = remux(TRAFFIC, tmp_path / "clean.mp4", "mp4", max_frames=200)
    damaged = tmp_path / "damaged.mp4"
    damaged.write_bytes(delete_bytes(clean.read_bytes(), 20, seed=1))
    source = open_source(str(damaged), CaptureConfig(reference=str(clean)))
    frames = list(source.frames())
    assert len(frames) >= 0.75 * 200        # 167 measured; 15 when salvage stopped at the first gap
    assert "unreadable bytes skipped" in source.stats.summary()
    assert source.stats.damaged >= 0.5 * len(frames)


def test_mkv_cluster_checksum_catches_damage_the_decoder_cannot_see(tmp_path):
    """A flipped bit that still decodes (fuzz cases 49 and 160 of docs/results.md) fails the CRC-32."""
    from damage_corpus import remux
    from stages.mkv_checksums import damaged_clusters

    clean = remux(SAMPLE, tmp_path / "clean.mkv", "mkv", max_frames=36)
    assert damaged_clusters(clean) == []
    data = bytearray(clean.read_bytes())
    cluster = data.find(b"\x1f\x43\xb6\x75")
    data[cluster + 15000] ^= 0x10            # inside the first cluster's frame data
    damaged = tmp_path / "damaged.mkv"
    damaged.write_bytes(bytes(data))
    assert [start for start, _ in damaged_clusters(damaged)] == [cluster]
    frames = list(open_source(str(damaged), CaptureConfig()).frames())
    differing = damaged_against(decode_all(clean), {f.index: f.image for f in frames})
    flagged = {f.index for f in frames if f.damage}
    assert differing <= flagged and 0 in flagged
    assert any("checksum" in f.damage for f in frames)


def test_avi_frames_are_counted_not_timed_by_decode_order_stamps():
    tracker = DamageTracker(fps=10.0, use_stamps=False)
    frames = [tracker.next_frame(_frame(t, key=i == 0), []).frame for i, t in enumerate([0.1, 0.3, 0.4, 0.2])]
    assert [(f.index, round(f.time_s, 6), f.damage) for f in frames] == [
        (0, 0.0, ""), (1, 0.1, ""), (2, 0.2, ""), (3, 0.3, "")]
