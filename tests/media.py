"""Test media made on the fly: small videos and tiny ONNX height models (no torch needed but for
``export_contact_net``, which exports a torch network)."""

from __future__ import annotations

import http.server
import json
import signal
import socketserver
import threading
import time
from pathlib import Path

import cv2
import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_REAL = REPO_ROOT.parent / "shared" / "real"


def make_tiny_height_model(path: Path, width: int = 64, height: int = 48,
                           units: str = "camera_height_fraction", input_shape=None) -> Path:
    """A two-head ONNX model with heightpipe metadata: height from brightness, ground from darkness.

    Not a trained network: it lets pipeline tests run without torch or the shipped model.
    Bright pixels come out 'high', so a white box on a dark floor is an object.
    """
    import onnx
    from onnx import TensorProto, helper

    shape = input_shape or [1, 3, height, width]
    w_height = np.full((1, 3, 1, 1), 0.15, np.float32)   # ~0.45 x camera height for white
    w_ground = np.full((1, 3, 1, 1), -2.0, np.float32)
    b_ground = np.array([1.0], np.float32)
    nodes = [
        helper.make_node("Conv", ["image", "w_height"], ["height_raw"]),
        helper.make_node("Relu", ["height_raw"], ["height"]),
        helper.make_node("Conv", ["image", "w_ground", "b_ground"], ["ground_logit"]),
    ]
    graph = helper.make_graph(
        nodes, "tiny_heightnet",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, shape)],
        [helper.make_tensor_value_info("height", TensorProto.FLOAT, [1, 1, height, width]),
         helper.make_tensor_value_info("ground_logit", TensorProto.FLOAT, [1, 1, height, width])],
        initializer=[helper.make_tensor("w_height", TensorProto.FLOAT, w_height.shape, w_height.ravel()),
                     helper.make_tensor("w_ground", TensorProto.FLOAT, w_ground.shape, w_ground.ravel()),
                     helper.make_tensor("b_ground", TensorProto.FLOAT, [1], b_ground)])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    meta = {"heightpipe.format_version": "1", "heightpipe.input_width": str(width),
            "heightpipe.input_height": str(height), "heightpipe.mean": json.dumps([0.5, 0.5, 0.5]),
            "heightpipe.std": json.dumps([0.5, 0.5, 0.5]), "heightpipe.color_order": "RGB",
            "heightpipe.output_units": units, "heightpipe.architecture": "tiny-test"}
    helper.set_model_props(model, meta)
    onnx.save(model, str(path))
    return path


def write_moving_box_video(path: Path, frames: int = 30, size=(160, 120), fps: float = 10.0) -> Path:
    """A dark floor with a white box walking across: an easy 'object' for the tiny model."""
    width, height = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    assert writer.isOpened()
    rng = np.random.default_rng(0)
    floor = (rng.random((height, width, 3)) * 40).astype(np.uint8)
    for i in range(frames):
        image = floor.copy()
        x = 10 + i * (width - 40) // max(1, frames - 1)
        cv2.rectangle(image, (x, height // 3), (x + 16, height // 3 + 40), (255, 255, 255), -1)
        writer.write(image)
    writer.release()
    return path


def project(camera, points):
    """World points (N x 3) to pixels through a ``stages.ground_contact`` camera (K, R, centre C)."""
    p = (camera.K @ (camera.R @ (np.asarray(points, float) - camera.C).T)).T
    return p[:, :2] / p[:, 2:]


def pole_scene(values=(0.5236, 0.0349, -0.1054), size=(320, 240), poles=8, seed=0):
    """A grey picture of poles standing on flat ground 6 m below a camera of ``values`` (pitch and
    roll in radians, log focal length in image heights: 30 degrees, 2 degrees, 0.9 by default),
    the poles' image segments (foot to top) and the camera: straight lines to read a camera from."""
    import math

    from stages.ground_contact import camera_from_angles

    width, height = size
    camera = camera_from_angles(width, height, 6.0, values[0], values[1], math.exp(values[2]) * height)
    rng = np.random.default_rng(seed)
    image = np.full((height, width), 90, np.uint8)
    segments = []
    for _ in range(poles):
        x, y = rng.uniform(-6, 6), rng.uniform(9, 20)
        foot, top = project(camera, [[x, y, 0.0], [x, y, 4.0]])
        cv2.line(image, tuple(np.round(foot).astype(int)), tuple(np.round(top).astype(int)), 220, 5)
        segments.append([*foot, *top])
    return image, np.array(segments), camera


def write_lens_calibration(path: Path, dist: list[float] | None = None, pose: bool = False) -> Path:
    """A calibration JSON for the 320x240 pole scene's lens (focal 216 px): the lens alone, or
    with ``dist`` and (``pose``) a 6 m, 30 degree pose."""
    data: dict = {"image_size": [320, 240], "K": [[216.0, 0, 159.5], [0, 216.0, 119.5], [0, 0, 1]]}
    if dist is not None:
        data["dist"] = dist
    if pose:
        data.update({"camera_height_m": 6.0, "pitch_deg": 30.0})
    path.write_text(json.dumps(data))
    return path


def write_pole_video(path: Path, frames: int = 30, fps: float = 10.0) -> Path:
    """The pole scene (``pole_scene``, 320x240) with a dark box walking across: a video whose
    camera can be read from its straight lines."""
    poles = cv2.cvtColor(pole_scene()[0], cv2.COLOR_GRAY2BGR)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (320, 240))
    assert writer.isOpened()
    for i in range(frames):
        image = poles.copy()
        x = 20 + i * 240 // max(1, frames - 1)
        cv2.rectangle(image, (x, 150), (x + 14, 200), (20, 20, 20), -1)
        writer.write(image)
    writer.release()
    return path


def write_truncated_avi(path: Path, frames: int = 40) -> Path:
    """An MJPEG AVI whose second half is cut off: its header promises ``frames`` frames."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for i in range(frames):
        writer.write(np.full((48, 64, 3), i * 5, np.uint8))
    writer.release()
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


def make_sink_packet(index: int, with_maps: bool = True, with_ground: bool = True):
    """A 64x48 frame with a 1.72 m object for the sink tests; track 1 confirmed from frame 4,
    track 2 always, track 3 never. ``with_maps=False`` drops the height map and the matches."""
    from core.packets import CameraInfo, FeatureMatches, Frame, FramePacket, Track

    width, height_px = 64, 48
    rng = np.random.default_rng(index)
    height = np.zeros((height_px, width), np.float32)
    height[10:30, 20:30] = 1.72
    points = rng.uniform(0, [width, height_px], (30, 2)).astype(np.float32)
    tracks = [Track(1, (20, 10, 10, 20), "person", 1.72, 0.04, confirmed=index >= 4),
              Track(2, (5, 5, 8, 8), "vehicle", 1.2, 0.3, confirmed=True),
              Track(3, (40, 30, 5, 5), "other", 0.6, 0.5, confirmed=False)]
    return FramePacket(
        frame=Frame(index, index / 10, rng.integers(0, 255, (height_px, width, 3), dtype=np.uint8)),
        camera=CameraInfo(width, height_px, K=np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])),
        ground_mask=height < 0.1 if with_ground else None,
        height_map=height if with_maps else None,
        matches=FeatureMatches(points, points + 1, np.arange(30) < 10) if with_maps else None,
        tracks=tracks)


def write_unfinished_recording(path: Path, frames: int = 35) -> bytes:
    """An MCAP of ``frames`` sink packets at 10 fps (chunks closed every second) whose last third
    is cut off, as a killed writer leaves it; returns the bytes left."""
    from core.config import OutputConfig
    from stages.mcap_sink import McapSink

    sink = McapSink(path, OutputConfig(flush_interval_s=1.0))
    for index in range(frames):
        sink.write(make_sink_packet(index))
    sink.close()
    data = path.read_bytes()[:path.stat().st_size * 2 // 3]
    path.write_bytes(data)
    return data


def rrd_rows(path: Path, extra_columns: tuple[str, ...] = ()) -> dict[str, list[tuple[int, dict]]]:
    """Temporal rows of an .rrd per entity, (frame, {component: value}), sorted by frame.

    Component columns ("Archetype:field") are kept, plus ``extra_columns`` (e.g. the "time" index).
    """
    from collections import defaultdict

    from rerun.chunk import RrdReader

    rows: dict[str, list[tuple[int, dict]]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        columns = {name: batch.column(name).to_pylist() for name in batch.schema.names
                   if ":" in name or name in extra_columns}
        for i, frame in enumerate(batch.column("frame").to_pylist()):
            rows[chunk.entity_path].append((frame, {name: values[i] for name, values in columns.items()}))
    return {entity: sorted(items, key=lambda item: item[0]) for entity, items in rows.items()}


def default_sigint() -> None:
    """``preexec_fn`` for a child that must take Ctrl-C: a shell's background job (nohup, ``&``)
    starts its children with SIGINT ignored, and heightpipe keeps an inherited SIG_IGN (as a batch
    worker must), so without this the SIGINT tests fail whenever the suite itself runs in the
    background."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def export_contact_net(folder: Path, net, width: int, height: int) -> Path:
    """A ``heightnet.contact_model.ContactNet`` (trained at ``width`` x ``height``) saved as a
    training state in ``folder`` and exported as the run time reads it: folder/heightnet_v2.onnx
    (torch is imported here, where a test needs it)."""
    import torch

    from core.config import TrainV2Config
    from heightnet.contact_export import export_contact
    from heightnet.contact_train import save_state

    state = folder / "checkpoint.pt"
    save_state(state, net, torch.optim.Adam(net.parameters()), step=1, images=2,
               config=TrainV2Config(out=str(folder), input_width=width, input_height=height))
    path = folder / "heightnet_v2.onnx"
    export_contact(state, path)
    return path


def make_tiny_contact_model(path: Path, offsets: np.ndarray, camera: np.ndarray,
                            camera_slope: np.ndarray | None = None, extra_outputs: bool = True,
                            detection: tuple[list[str], np.ndarray, np.ndarray] | None = None) -> Path:
    """A HeightNet v2-shaped ONNX model (ground-contact offsets) with outputs chosen by the test.

    ``offsets`` (H x W x 2, input pixels) come out as they are, whatever the image; the camera
    heads give ``camera + camera_slope * mean(normalised image)`` (6 numbers), so frames of
    different brightness read differently; the ground is dark pixels, as the v1 tiny model's.
    ``extra_outputs`` adds a detector's ``centre_logit`` and ``box`` that the metadata does not
    declare, which the run time must ignore. ``detection`` = (classes, centre logits C x h x w,
    boxes 4 x h x w) makes a declared detection head instead (``heightpipe.outputs``, stride =
    input height / h) whose outputs are these constants. Not a trained network: it proves the
    wiring without torch.
    """
    import onnx
    from onnx import TensorProto, helper

    height, width = offsets.shape[:2]
    offsets_nchw = np.ascontiguousarray(offsets.transpose(2, 0, 1)[None], np.float32)
    slope = np.zeros(6, np.float32) if camera_slope is None else np.asarray(camera_slope, np.float32)
    constants = {"offsets_value": offsets_nchw, "w_ground": np.full((1, 3, 1, 1), -2.0, np.float32),
                 "b_ground": np.array([1.0], np.float32),
                 "camera_bias": np.asarray(camera, np.float32).reshape(1, 6), "camera_slope": slope.reshape(1, 6),
                 "centre_value": np.zeros((1, 1, height, width), np.float32),
                 "box_value": np.ones((1, 4, height, width), np.float32)}
    nodes = [
        helper.make_node("Identity", ["offsets_value"], ["offsets"]),
        helper.make_node("Conv", ["image", "w_ground", "b_ground"], ["ground_logit"]),
        helper.make_node("ReduceMean", ["image"], ["brightness"], axes=[1, 2, 3], keepdims=0),
        helper.make_node("Unsqueeze", ["brightness", "one_axis"], ["brightness_2d"]),
        helper.make_node("Mul", ["brightness_2d", "camera_slope"], ["camera_varying"]),
        helper.make_node("Add", ["camera_varying", "camera_bias"], ["camera"]),
    ]
    outputs = [helper.make_tensor_value_info("offsets", TensorProto.FLOAT, [1, 2, height, width]),
               helper.make_tensor_value_info("ground_logit", TensorProto.FLOAT, [1, 1, height, width]),
               helper.make_tensor_value_info("camera", TensorProto.FLOAT, [1, 6])]
    if detection is not None:
        classes, centre, boxes = detection
        constants["centre_value"] = np.asarray(centre, np.float32)[None]
        constants["box_value"] = np.asarray(boxes, np.float32)[None]
        nodes += [helper.make_node("Identity", ["centre_value"], ["centre_logit"]),
                  helper.make_node("Identity", ["box_value"], ["box"])]
        outputs += [helper.make_tensor_value_info(name, TensorProto.FLOAT, list(constants[f"{value}_value"].shape))
                    for name, value in (("centre_logit", "centre"), ("box", "box"))]
    elif extra_outputs:
        nodes += [helper.make_node("Identity", ["centre_value"], ["centre_logit"]),
                  helper.make_node("Identity", ["box_value"], ["box"])]
        outputs = [helper.make_tensor_value_info("centre_logit", TensorProto.FLOAT, [1, 1, height, width]),
                   *outputs, helper.make_tensor_value_info("box", TensorProto.FLOAT, [1, 4, height, width])]
    initializers = [helper.make_tensor(name, TensorProto.FLOAT, value.shape, value.ravel())
                    for name, value in constants.items()]
    initializers.append(helper.make_tensor("one_axis", TensorProto.INT64, [1], [0]))
    graph = helper.make_graph(
        nodes, "tiny_contact_net",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, height, width])],
        outputs, initializer=initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    meta = {"heightpipe.format_version": "2", "heightpipe.input_width": str(width),
            "heightpipe.input_height": str(height), "heightpipe.mean": json.dumps([0.5, 0.5, 0.5]),
            "heightpipe.std": json.dumps([0.5, 0.5, 0.5]), "heightpipe.color_order": "RGB",
            "heightpipe.output_units": "ground_contact_offsets", "heightpipe.architecture": "tiny-test"}
    if detection is not None:
        meta["heightpipe.outputs"] = json.dumps({"centre_logit": {"classes": list(detection[0]),
                                                                  "stride": height // np.shape(detection[1])[1]},
                                                 "box": "centre dx, dy, width, height; input pixels"})
    helper.set_model_props(model, meta)
    onnx.save(model, str(path))
    return path


def mjpeg_server(frames_per_connection: list[int], fps: float | None = None,
                 sizes_per_connection: list[tuple[int, int]] = ((64, 48),), picture: np.ndarray | None = None):
    """An IP-camera-like MJPEG stream that drops the k-th connection after
    ``frames_per_connection[k]`` frames of ``sizes_per_connection[k]`` (width, height) pixels
    (the last entry of each repeats), sent as fast as the socket takes them or paced at ``fps``;
    flat frames whose grey changes every frame, or ``picture`` (BGR) at that size.
    Returns (server, connections).
    """
    connections = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):
            connections.append(1)
            count = frames_per_connection[min(len(connections), len(frames_per_connection)) - 1]
            width, height = sizes_per_connection[min(len(connections), len(sizes_per_connection)) - 1]
            self.send_response(200)
            self.send_header("Content-Type", "multipart/x-mixed-replace;boundary=frame")
            self.end_headers()
            for i in range(count):
                image = (np.full((height, width, 3), i * 8 % 255, np.uint8) if picture is None
                         else cv2.resize(picture, (width, height)))
                jpg = cv2.imencode(".jpg", image)[1].tobytes()
                try:
                    self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n"
                                     % len(jpg) + jpg + b"\r\n")
                except (BrokenPipeError, ConnectionResetError):
                    return
                if fps:
                    time.sleep(1.0 / fps)

    class Server(socketserver.ThreadingMixIn, http.server.HTTPServer):
        daemon_threads = True

    server = Server(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, connections
