"""PREFIX.events.jsonl and the webhook, against a real HTTP server on 127.0.0.1."""

from __future__ import annotations

import json
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest

from core.config import EventsConfig
from core.errors import ConfigError
from core.packets import CameraInfo, Frame, FramePacket
from stages.events_sink import EventsSink
from stages.height_rules import RuleEvent
from stages.webhook import WebhookPoster


class Endpoint:
    """An HTTP server that answers the first ``failures`` POSTs with 500, then 200."""

    def __init__(self, failures: int = 0):
        self.bodies: list[dict] = []
        self.attempts = 0
        endpoint = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):  # noqa: N802 (http.server's name)
                endpoint.attempts += 1
                body = self.rfile.read(int(self.headers["Content-Length"]))
                if endpoint.attempts <= failures:
                    self.send_response(500)
                else:
                    endpoint.bodies.append(json.loads(body))
                    self.send_response(200)
                self.end_headers()

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/events"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture
def endpoint_factory():
    endpoints = []

    def make(failures: int = 0) -> Endpoint:
        endpoints.append(Endpoint(failures))
        return endpoints[-1]

    yield make
    for endpoint in endpoints:
        endpoint.close()


def dead_url() -> str:
    """A port on 127.0.0.1 nobody listens on (connection refused)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    return f"http://127.0.0.1:{port}/events"


def event_packet(index: int, events: int) -> FramePacket:
    packet = FramePacket(frame=Frame(index, index / 10, np.zeros((4, 4, 3), np.uint8)), camera=CameraInfo(4, 4))
    packet.events = [RuleEvent("tall", 100 * index + k, "vehicle", index, index / 10, 4.0, 0.05, "box",
                               (1.0, 2.0, 3.0, 4.0), None) for k in range(events)]
    return packet


def write_events(tmp_path, config: EventsConfig, frames: int = 5, per_frame: int = 2) -> EventsSink:
    sink = EventsSink(tmp_path / "run.events.jsonl", config, "run")
    for index in range(frames):
        sink.write(event_packet(index, per_frame))
    sink.close()
    return sink


def read_jsonl(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_every_event_is_a_line_and_a_post(tmp_path, endpoint_factory):
    endpoint = endpoint_factory()
    sink = write_events(tmp_path, EventsConfig(webhook_url=endpoint.url))
    lines = read_jsonl(tmp_path / "run.events.jsonl")
    assert [line["track_id"] for line in lines] == [0, 1, 100, 101, 200, 201, 300, 301, 400, 401]
    assert lines[0]["recording"] == "run" and lines[0]["height_m"] == 4.0 and "written_at" in lines[0]
    assert sorted(body["track_id"] for body in endpoint.bodies) == [line["track_id"] for line in lines]
    assert sink.webhook_stats.posted == 10 and sink.webhook_stats.failed == 0


def test_a_failing_endpoint_is_retried(tmp_path, endpoint_factory):
    endpoint = endpoint_factory(failures=2)  # the first event needs three attempts
    sink = write_events(tmp_path, EventsConfig(webhook_url=endpoint.url, webhook_retries=3,
                                               webhook_backoff_s=0.01), frames=2, per_frame=1)
    assert endpoint.attempts == 4 and len(endpoint.bodies) == 2
    assert sink.webhook_stats.posted == 2 and sink.webhook_stats.failed == 0


def test_an_endpoint_that_keeps_failing_gives_up_and_says_so(tmp_path, endpoint_factory):
    endpoint = endpoint_factory(failures=1000)
    sink = write_events(tmp_path, EventsConfig(webhook_url=endpoint.url, webhook_retries=1,
                                               webhook_backoff_s=0.01), frames=3, per_frame=1)
    assert endpoint.attempts == 6, "each event: one attempt and one retry"
    assert sink.webhook_stats.failed == 3 and "HTTP 500" in sink.webhook_stats.summary()
    assert len(read_jsonl(tmp_path / "run.events.jsonl")) == 3, "the JSONL keeps every event"


def test_a_dead_url_neither_blocks_the_writer_nor_loses_jsonl_lines(tmp_path):
    config = EventsConfig(webhook_url=dead_url(), webhook_retries=2, webhook_backoff_s=0.2)
    sink = EventsSink(tmp_path / "run.events.jsonl", config, "run")
    start = time.perf_counter()
    for index in range(50):
        sink.write(event_packet(index, 2))
    writing_s = time.perf_counter() - start
    sink.close()
    assert writing_s < 1.0, "posting happens on the webhook's own thread"
    assert len(read_jsonl(tmp_path / "run.events.jsonl")) == 100
    stats = sink.webhook_stats
    assert stats.posted == 0 and stats.failed + stats.dropped == 100
    assert "refused" in stats.last_error.lower()


def test_a_full_queue_drops_posts_not_lines(tmp_path):
    poster = WebhookPoster(EventsConfig(webhook_url=dead_url(), webhook_queue=2, webhook_retries=5,
                                        webhook_backoff_s=1.0), close_wait_s=0.1)
    for k in range(10):
        poster.post({"k": k})
    poster.close()
    assert poster.stats.posted == 0 and poster.stats.failed + poster.stats.dropped == 10


@pytest.mark.parametrize("config, message", [
    (EventsConfig(webhook_url="ftp://x"), "http"),
    (EventsConfig(webhook_url="http://x", webhook_timeout_s=0), "webhook_timeout_s"),
    (EventsConfig(webhook_url="http://x", webhook_queue=0), "webhook_queue"),
])
def test_bad_webhook_config(config, message):
    with pytest.raises(ConfigError, match=message):
        WebhookPoster(config)
