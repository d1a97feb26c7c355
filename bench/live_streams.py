"""Live cameras on this machine: N paced network streams, one `heightpipe run` per camera.

    python -m bench.live_streams [--cameras 2] [--fps 25] [--seconds 60] [--clip CLIP]
                                 [--set SECTION.KEY=VALUE ...]

Each camera is a local server that sends the clip (looped, its packets copied, not re-encoded)
as an MPEG-TS stream over TCP at ``--fps`` frames per second of wall time, as an IP camera
would; each run reads its stream with the pipeline's live source (``tcp://127.0.0.1:PORT``) in
its own process, all outputs on, and ends when its stream does. A run that cannot keep up
either drops frames (the overlapped run's live queue is full: counted by the pipeline) or,
frames piling up in the socket, makes its server late (the time a send came after its
schedule, worst case, printed). Before it drops, a run behind gives frames the last network
outputs (``run.reuse_backlog``; counted, and their share printed). Live means: every frame sent
was processed, none dropped and no server late by more than a frame or two.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import socket
import tempfile
import time
from fractions import Fraction
from pathlib import Path

from bench.clips import SAMPLE


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def serve_stream(clip: str, port: int, fps: float, seconds: float, results) -> None:
    """Waits for one client on ``port``, then sends the clip's packets at ``fps`` for ``seconds``."""
    import av
    from av.bitstream import BitStreamFilterContext

    source = av.open(clip)  # open while its packets are used: they point into its buffers
    video = source.streams.video[0]
    # An MP4 keeps the decoder's set-up (extradata) in its header, a transport stream in the
    # key frames: copy it there, as a camera's encoder would send it.
    in_band = BitStreamFilterContext("dump_extra=freq=keyframe", video)
    packets = [out for packet in source.demux(video) if packet.size for out in in_band.filter(packet)]
    with source, av.open(f"tcp://127.0.0.1:{port}?listen=1", "w", format="mpegts") as out:
        stream = out.add_stream_from_template(video)
        time_base = Fraction(1, 90000)
        total = int(round(seconds * fps))
        late_s = 0.0
        start = 0.0  # set once the first packet is out: the first write waits for the client
        for n in range(total):
            if n:
                wait = start + n / fps - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
                else:
                    late_s = max(late_s, -wait)
            packet = packets[n % len(packets)]
            packet.stream = stream
            packet.time_base = time_base
            packet.pts = packet.dts = int(round(n * 90000 / fps))
            out.mux(packet)
            if not n:
                start = time.perf_counter()
    results.put({"port": port, "sent": total, "late_s": late_s})


def run_camera(url: str, overrides: list[str], out_dir: str, results) -> None:
    """One live camera's `heightpipe run`, in its own process."""
    from core.config import load_config
    from pipeline.runner import run_pipeline

    config = load_config(None, overrides)
    config.output.progress = False
    port = int(url.rsplit(":", 1)[1])
    summary = run_pipeline(url, config, Path(out_dir) / f"cam_{port}")
    results.put({"port": port, "frames": summary.frames, "dropped": summary.dropped_frames,
                 "reused": summary.reused_network_frames,
                 "fps": summary.fps, "network_ms": summary.ms_per_frame().get("ground", 0.0),
                 "total_ms": summary.total_ms_per_frame()})


def main() -> None:
    os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=error")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip", type=Path, default=SAMPLE)
    parser.add_argument("--cameras", type=int, default=2)
    parser.add_argument("--fps", type=float, default=25.0, help="frames per second each camera sends")
    parser.add_argument("--seconds", type=float, default=60.0, help="how long each camera sends")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    args = parser.parse_args()

    # The stream's end is the run's end: no reconnects, and a short read timeout after it.
    overrides = ["capture.reconnect_attempts=0", "capture.read_timeout_s=3", *args.overrides]
    context = multiprocessing.get_context("spawn")
    served, processed = context.Queue(), context.Queue()
    ports = [free_port() for _ in range(args.cameras)]
    servers = [context.Process(target=serve_stream, args=(str(args.clip), port, args.fps, args.seconds, served))
               for port in ports]
    load = os.getloadavg()[0]
    for server in servers:
        server.start()
    time.sleep(1.0)  # the servers listen before the runs connect
    with tempfile.TemporaryDirectory() as out_dir:
        runs = [context.Process(target=run_camera, args=(f"tcp://127.0.0.1:{port}", overrides, out_dir, processed))
                for port in ports]
        for run in runs:
            run.start()
        sent = {item["port"]: item for item in (served.get() for _ in servers)}
        got = {item["port"]: item for item in (processed.get() for _ in runs)}
        for process in (*servers, *runs):
            process.join()

    print(f"{args.cameras} live camera(s), {args.fps:g} frames/s each for {args.seconds:g} s "
          f"({args.clip.name}); load average {load:.1f} at the start")
    print("| camera | frames sent | frames processed | of them, network reused | dropped | "
          "server late, worst (ms) | frames/s | network ms (a run of it) | stage ms per frame |")
    print("|---|---|---|---|---|---|---|---|---|")
    live = True
    reused = 0
    for i, port in enumerate(ports, 1):
        s, g = sent[port], got[port]
        print(f"| {i} | {s['sent']} | {g['frames']} | {g['reused']} | {g['dropped']} | {1000 * s['late_s']:.0f} | "
              f"{g['fps']:.1f} | {g['network_ms']:.1f} | {g['total_ms']:.1f} |")
        live &= g["dropped"] == 0 and g["frames"] >= s["sent"] and s["late_s"] <= 2.0 / args.fps
        reused += g["reused"]
    frames = max(1, sum(g["frames"] for g in got.values()))
    shed = f"; the network skipped (last outputs reused) on {100 * reused / frames:.0f} % of them" if reused else ""
    print(f"live: every frame processed, none dropped, no server late by more than two frames{shed}"
          if live else f"NOT live: frames dropped, lost, or a server was held up{shed}")


if __name__ == "__main__":
    main()
