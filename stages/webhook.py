"""POSTs events as JSON to a URL on a background thread, with retries.

The frame loop only puts an event on a queue: a slow, failing or dead endpoint costs it
nothing, and the run never waits for it except briefly at the end (``close``). Each event is
tried ``1 + retries`` times with doubling back-off; one that still fails, or that finds the
queue full, is counted as lost to the webhook (it is in PREFIX.events.jsonl regardless).
"""

from __future__ import annotations

import json
import queue
import threading
import time
import urllib.error
import urllib.request
from dataclasses import dataclass

from core.config import EventsConfig
from core.errors import ConfigError

_STOP = object()


@dataclass
class WebhookStats:
    posted: int = 0
    failed: int = 0
    """Given up after every retry."""
    dropped: int = 0
    """Not tried: the queue was full, or the run ended before their turn."""
    last_error: str = ""

    def summary(self) -> str:
        text = f"{self.posted} posted"
        if self.failed or self.dropped:
            text += f", {self.failed} failed, {self.dropped} not sent"
        if self.last_error:
            text += f" (last error: {self.last_error})"
        return text


def check_webhook_config(config: EventsConfig) -> None:
    if config.webhook_url and not config.webhook_url.startswith(("http://", "https://")):
        raise ConfigError(f"events.webhook_url must start with http:// or https://, got {config.webhook_url!r}")
    if config.webhook_timeout_s <= 0 or config.webhook_retries < 0 or config.webhook_backoff_s < 0:
        raise ConfigError("events.webhook_timeout_s must be > 0, webhook_retries and webhook_backoff_s >= 0")
    if config.webhook_queue < 1:
        raise ConfigError("events.webhook_queue must be >= 1")


class WebhookPoster:
    def __init__(self, config: EventsConfig, close_wait_s: float = 5.0):
        check_webhook_config(config)
        self.url = config.webhook_url
        self.timeout_s = config.webhook_timeout_s
        self.retries = config.webhook_retries
        self.backoff_s = config.webhook_backoff_s
        self.close_wait_s = close_wait_s
        """``close`` waits at most this long for events still queued; the rest count as not sent."""
        self.stats = WebhookStats()
        self._lock = threading.Lock()
        self._queue: queue.Queue = queue.Queue(maxsize=config.webhook_queue)
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._work, name="heightpipe-webhook", daemon=True)
        self._thread.start()
        self._closed = False

    def post(self, payload: dict) -> None:
        """Queue one event; never blocks."""
        try:
            self._queue.put_nowait(json.dumps(payload).encode("utf-8"))
        except queue.Full:
            with self._lock:
                self.stats.dropped += 1

    def _work(self) -> None:
        while True:
            body = self._queue.get()
            if body is _STOP:
                return
            if self._stopping.is_set():  # the run is over and the wait ran out
                outcome = "dropped"
            else:
                outcome = "posted" if self._deliver(body) else "failed"
            with self._lock:
                setattr(self.stats, outcome, getattr(self.stats, outcome) + 1)

    def _deliver(self, body: bytes) -> bool:
        delay = self.backoff_s
        for attempt in range(self.retries + 1):
            if attempt:
                if self._stopping.wait(delay):
                    return False
                delay *= 2
            request = urllib.request.Request(self.url, data=body, method="POST",
                                             headers={"Content-Type": "application/json"})
            try:
                with urllib.request.urlopen(request, timeout=self.timeout_s) as response:
                    if 200 <= response.status < 300:
                        return True
                    self.stats.last_error = f"HTTP {response.status}"
            except urllib.error.HTTPError as exc:
                self.stats.last_error = f"HTTP {exc.code}"
            except (urllib.error.URLError, OSError, ValueError) as exc:
                reason = getattr(exc, "reason", exc)
                self.stats.last_error = str(reason)
        return False

    def close(self) -> None:
        """Waits up to ``close_wait_s`` for queued events, then stops; idempotent."""
        if self._closed:
            return
        self._closed = True
        deadline = time.monotonic() + self.close_wait_s
        try:
            self._queue.put(_STOP, timeout=self.close_wait_s)
        except queue.Full:
            pass
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive():
            self._stopping.set()  # the worker now counts what is left as not sent, quickly
            self._queue.put(_STOP)
            self._thread.join(self.timeout_s + 1.0)
