"""PREFIX.events.jsonl: one JSON object per height-rule firing, and the optional webhook.

Each line is ``RuleEvent.to_dict()`` plus the recording name and the wall-clock time the event
was written (UTC, ISO 8601). The line is flushed before the event goes to the webhook, so a
dead endpoint, a crash or a kill never loses an event that fired.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

from core.config import EventsConfig
from core.errors import HeightpipeError
from core.packets import FramePacket
from stages.webhook import WebhookPoster, WebhookStats


def event_record(event, recording: str) -> dict:
    record = {"recording": recording, **event.to_dict()}
    record["written_at"] = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
    return record


class EventsSink:
    def __init__(self, path: Path, config: EventsConfig, recording_name: str):
        self.path = Path(path)
        self.recording_name = recording_name
        self.webhook = WebhookPoster(config) if config.webhook_url else None
        try:
            self._file = open(self.path, "w", encoding="utf-8")
        except OSError as exc:
            if self.webhook is not None:
                self.webhook.close()
            raise HeightpipeError(f"cannot write {self.path}: {exc.strerror}") from None
        self.count = 0

    def write(self, packet: FramePacket) -> None:
        for event in packet.events:
            record = event_record(event, self.recording_name)
            self._file.write(json.dumps(record) + "\n")
            self._file.flush()
            self.count += 1
            if self.webhook is not None:
                self.webhook.post(record)

    @property
    def webhook_stats(self) -> WebhookStats | None:
        return None if self.webhook is None else self.webhook.stats

    def close(self) -> None:
        self._file.close()
        if self.webhook is not None:
            self.webhook.close()
