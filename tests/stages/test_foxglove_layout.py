"""The shipped Foxglove layout is the one the module builds, and shows only topics the MCAP has."""

from __future__ import annotations

import json
import re
from pathlib import Path

from stages.foxglove_layout import layout_json

SHIPPED = Path(__file__).resolve().parents[2] / "docs" / "foxglove_layout.json"


def test_shipped_layout_is_up_to_date():
    assert SHIPPED.read_text() == layout_json(), "rebuild: python -m stages.foxglove_layout docs/foxglove_layout.json"


def test_layout_topics_are_written_by_the_mcap_sink():
    import stages.mcap_sink as mcap_sink

    written = set(re.findall(r"^    (/[\w/]+)", mcap_sink.__doc__, re.MULTILINE))
    text = json.dumps(json.loads(SHIPPED.read_text()))
    used = set(re.findall(r'"(/[a-z_/]+)', text)) | {m.split(".")[0] for m in re.findall(r'"(/[a-z_/]+\.)', text)}
    assert {"/camera/image", "/camera/annotations", "/camera/height", "/tracks", "/events",
            "/capture/damage", "/capture/network_skipped"} <= used
    assert used <= written, used - written
