"""The batch manifest: what `heightpipe batch` has done with each input, so a rerun resumes.

One JSON file, DIR/manifest.json, keyed by the input's resolved path. It is rewritten whole
after every finished task through a temporary file and ``os.replace``, so a kill at any
moment leaves either the previous or the new manifest, never a torn one. An entry counts
as finished only once its outputs were renamed into place; the manifest is the truth about
what is done, the files on disk are not.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from core.config import NETWORK_OBJECTS_KEYS, Config
from core.errors import HeightpipeError

MANIFEST_NAME = "manifest.json"
MANIFEST_VERSION = 1
HASH_BYTES = 64 * 1024
"""Bytes hashed at the head and at the tail of each input: catches an edit that keeps size
and mtime (or a copy over it) without reading months of footage. Part of the manifest's format
(a new value makes every finished input look changed), so a plain constant."""

DONE, FAILED, INTERRUPTED = "done", "failed", "interrupted"


@dataclass(frozen=True)
class InputIdentity:
    """What makes an input 'the same file' as last time; any difference means redo it."""

    size: int
    mtime_ns: int
    head_tail_sha1: str


def identify(path: Path) -> InputIdentity:
    stat = path.stat()
    digest = hashlib.sha1()
    with open(path, "rb") as f:
        digest.update(f.read(HASH_BYTES))
        if stat.st_size > 2 * HASH_BYTES:
            f.seek(-HASH_BYTES, os.SEEK_END)
        digest.update(f.read(HASH_BYTES))
    return InputIdentity(stat.st_size, stat.st_mtime_ns, digest.hexdigest())


def config_fingerprint(config: Config) -> str:
    """Hash of every setting that changes a video's outputs (not threads, progress, batch).

    The model file's size and mtime are part of it, so retraining into the same path redoes
    the archive.
    """
    from pipeline.scene_camera import knows_height_only
    from stages.heightnet_model import model_file

    relevant = {name: dataclasses.asdict(getattr(config, name))
                for name in ("capture", "ground", "height", "matching", "tracking", "camera", "output")}
    relevant["height"].pop("threads")
    if not config.height.input_width:
        # The trained input size, as before the key existed: archives made then are not redone.
        relevant["height"].pop("input_width")
    if not config.height.mirror:
        relevant["height"].pop("mirror")
    relevant["output"].pop("progress")
    relevant["output"].pop("directory")
    # Keys that came later and change nothing where they are not read: archives made before them
    # are not redone for them alone. The reading keys are read only by runs that know the camera's
    # height and none of its pose (a lens-only calibration file included).
    if not knows_height_only(config):
        for key in ("read_scene_frames", "read_scene_s", "read_scene_live_s"):
            relevant["camera"].pop(key)
    for key in ("pitch_std_deg", "roll_std_deg", "focal_std_pct"):
        if not relevant["camera"][key]:
            relevant["camera"].pop(key)
    # Object extraction's keys are hashed under "tracking", where they were before they got their
    # own [objects] section: archives processed before that are not redone for the move alone.
    objects = dataclasses.asdict(config.objects)
    if config.objects.source == "blobs":
        # The network-mode keys (and the source itself) came later and blobs mode reads none of them:
        # archives processed before they existed are not redone for them.
        for key in ("source", *NETWORK_OBJECTS_KEYS):
            objects.pop(key)
    relevant["tracking"].update(objects)
    model = model_file(config.height.model)
    if model.is_file():
        stat = model.stat()
        relevant["model_file"] = [str(model.resolve()), stat.st_size, stat.st_mtime_ns]
    text = json.dumps(relevant, sort_keys=True)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


@dataclass
class ManifestEntry:
    """One input and what became of it (times are ISO 8601 UTC, sizes in bytes)."""

    source: str
    output_name: str
    identity: InputIdentity
    config_fingerprint: str
    status: str
    """'done', 'failed' or 'interrupted'."""
    error: str = ""
    outputs: list[str] = field(default_factory=list)
    """Output files relative to DIR, present only for 'done'."""
    frames: int = 0
    failed_frames: int = 0
    duration_s: float = 0.0
    """Video time covered (decoded frames / the container's fps)."""
    video_fps: float = 0.0
    wall_s: float = 0.0
    """Compute time of the task, model loading included."""
    tracks: int = 0
    camera: str = ""
    """How the camera was known: 'calibration', 'camera-height', 'self' or 'none'."""
    started_at: str = ""
    finished_at: str = ""
    engine: str = ""
    worker: str = ""
    """host:pid of the process that ran it."""

    def to_json(self) -> dict:
        data = dataclasses.asdict(self)
        data["identity"] = dataclasses.asdict(self.identity)
        return data

    @classmethod
    def from_json(cls, data: dict) -> ManifestEntry:
        data = dict(data)
        data["identity"] = InputIdentity(**data["identity"])
        return cls(**data)


@dataclass
class Manifest:
    path: Path
    entries: dict[str, ManifestEntry] = field(default_factory=dict)

    @classmethod
    def load(cls, out_dir: Path) -> Manifest:
        path = out_dir / MANIFEST_NAME
        if not path.exists():
            return cls(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            if data.get("version") != MANIFEST_VERSION:
                raise ValueError(f"version {data.get('version')!r}")
            entries = {key: ManifestEntry.from_json(value) for key, value in data["inputs"].items()}
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise HeightpipeError(f"{path} is not a heightpipe batch manifest this version can read "
                                  f"({exc}); move it away to start the batch afresh") from None
        return cls(path, entries)

    def save(self) -> None:
        """Write to a temporary file and rename it over the manifest (atomic on POSIX)."""
        data = {"version": MANIFEST_VERSION,
                "inputs": {key: entry.to_json() for key, entry in sorted(self.entries.items())}}
        tmp = self.path.with_name(self.path.name + ".tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(data, f, indent=1)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path)

    def reason_to_run(self, key: str, identity: InputIdentity, fingerprint: str, out_dir: Path,
                      force: bool, retry_failed: bool) -> str | None:
        """Why this input must be processed now, or None to skip it."""
        entry = self.entries.get(key)
        if force:
            return "forced"
        if entry is None:
            return "new"
        if entry.identity != identity:
            return "file changed"
        if entry.config_fingerprint != fingerprint:
            return "config changed"
        if entry.status == DONE:
            missing = [name for name in entry.outputs if not (out_dir / name).is_file()]
            return f"output missing: {missing[0]}" if missing else None
        if entry.status == FAILED:
            return "retry failed" if retry_failed else None
        return "unfinished"
