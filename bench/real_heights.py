"""Metric heights on real footage: Oxford Town Centre in each calibration mode, against its labels.

Runs ``heightpipe run`` on ``../shared/real/oxford_towncentre/oxford_snipped.mp4`` as a user would,
once per mode, and compares the confirmed person tracks of ``PREFIX.tracks.csv`` with
``gt_with_geometry.csv`` (per-person head-top and foot points and heights, 1.80 m for everyone
in this clip):

* ``calibration``: ``--calibration calib_opencv.json`` (frames undistorted, geometry on);
* ``camera-height``: ``--camera-height 7.84`` only (HeightNet v2 by default, its camera heads giving
  pitch and focal length; v1 with ``--set height.model=v1``: network height x camera height);
* ``self``: ``heightpipe calibrate`` on the clip first (with the file's intrinsics only), then
  a run with the snippet it prints; a refusal is reported as such;
* ``scene``: ``heightpipe calibrate --camera-height 7.84`` (nothing else known: pitch, roll and
  focal length from HeightNet v2's heads and the scene's lines), then a run with its snippet.

Per mode: confirmed person tracks, their mean / min / max final height, how many lie outside
1.5-2.1 m, the median error of tracks matched to a labelled person and the share of them within
``WITHIN_M`` (10 cm), and the median pixel error of the tracks' head-top and foot points (top and bottom
centre of the track box) against the labelled points, in the frame the run worked in
(undistorted where it undistorted).

And how well the labelled people are tracked (:func:`identity_scores`): the share of labelled
person-frames a track box covers (one-to-one, IoU >= 0.5 with the body box as far as it lies in
the frame: the labels' boxes of people at its edges go on outside it), the identity recall
IDR (the share covered by the one track id assigned to each person, as IDF1 assigns them), ID
switches, and the people covered in at least 80 % of their frames. Recall only: some people at
the frame's edges are not labelled, so a track without a label is not a false positive.

With ``--misses``, what lies over the labelled person-frames no track box covers
(:func:`uncovered_breakdown`, the rules of ``heightpipe eval-tracks --misses``): a track box
holding several people, one that is off the person (and which of its edges is off the most: short
of the feet, short of the crown, or off to a side), or none near.

    python -m bench.real_heights [--modes calibration,camera-height,self,scene] [--out runs/real_heights]
                                 [--picture docs/oxford_heights.jpg [--picture-frame 60]] [--misses]
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

OXFORD = Path(__file__).resolve().parents[2] / "shared" / "real" / "oxford_towncentre"
VIDEO = OXFORD / "oxford_snipped.mp4"
CALIBRATION = OXFORD / "calib_opencv.json"
LABELS = OXFORD / "gt_with_geometry.csv"
CAMERA_HEIGHT_M = 7.84
PERSON_RANGE_M = (1.5, 2.1)
MATCH_IOU = 0.3
WITHIN_M = 0.10
MOSTLY_TRACKED = 0.8
MODES = ("calibration", "camera-height", "self", "scene")
UNCOVERED_KINDS = ("covered", "under a box holding several", "box short of the feet", "box short of the crown",
                   "box off to a side", "no track box near")


@dataclass
class LabelledPerson:
    person: int
    box: np.ndarray       # x, y, w, h in the run's frame
    head: np.ndarray      # head-top point (u, v)
    foot: np.ndarray      # foot point (u, v)
    foot_inside: bool
    height_m: float


@dataclass
class ModeResult:
    mode: str
    note: str = ""
    persons: int = 0
    mean_m: float = float("nan")
    min_m: float = float("nan")
    max_m: float = float("nan")
    outside: int = 0
    matched: int = 0
    median_error_m: float = float("nan")
    within: float = float("nan")
    """The share of matched tracks within ``WITHIN_M`` of the truth: steadier than the median of
    some twenty tracks, whose errors fall in two groups (a few cm, and tens of cm)."""
    head_px: float = float("nan")
    foot_px: float = float("nan")
    identity: IdentityScores | None = None
    uncovered: dict[str, int] | None = None


@dataclass
class IdentityScores:
    """How the labelled people are tracked (recall side only: see the module's docstring)."""

    person_frames: int
    covered: float
    id_recall: float
    id_switches: int
    mostly_tracked: int
    people: int


def load_labels(undistort: bool) -> dict[int, list[LabelledPerson]]:
    """Labelled people per frame, points moved into the undistorted frame if the run undistorted."""
    from stages.calibration import load_calibration, undistort_pixels

    camera = load_calibration(CALIBRATION)
    frames: dict[int, list[LabelledPerson]] = {}
    with open(LABELS, newline="") as f:
        for row in csv.DictReader(f):
            if row["body_valid"] != "1" or row["head_valid"] != "1":
                continue
            x1, y1, x2, y2 = (float(row[k]) for k in ("body_x1", "body_y1", "body_x2", "body_y2"))
            points = np.array([[float(row["headtop_u"]), float(row["headtop_v"])],
                               [float(row["foot_u"]), float(row["foot_v"])],
                               [x1, y1], [x2, y1], [x1, y2], [x2, y2]])
            if undistort:
                points = undistort_pixels(camera, points)
            # The body box as far as it is in view: a person half out of the frame is covered by
            # a track on the half that is in it (the labelled box goes on past the frame's edge).
            corners = np.clip(points[2:], 0.0, [camera.width, camera.height])
            box = np.array([*corners.min(0), *(corners.max(0) - corners.min(0))])
            frames.setdefault(int(row["frame"]), []).append(LabelledPerson(
                int(row["person"]), box, points[0], points[1], row["foot_inside_image"] == "1",
                float(row["height_headtop_m"])))
    return frames


def read_tracks(path: Path) -> dict[int, list[dict]]:
    rows: dict[int, list[dict]] = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            rows.setdefault(int(row["frame"]), []).append(row)
    return rows


def score(mode: str, tracks_csv: Path, undistorted: bool) -> ModeResult:
    """Compare a run's confirmed person tracks with the labels."""
    labels = load_labels(undistorted)
    by_frame = read_tracks(tracks_csv)
    final: dict[int, dict] = {}
    for frame in sorted(by_frame):
        for row in by_frame[frame]:
            final[int(row["track_id"])] = row
    persons = {tid: float(row["height_m"]) for tid, row in final.items() if row["class"] == "person"}
    heights = np.array([h for h in persons.values() if np.isfinite(h)])
    result = ModeResult(mode, persons=len(persons))
    if heights.size:
        result.mean_m, result.min_m, result.max_m = heights.mean(), heights.min(), heights.max()
        result.outside = int(((heights < PERSON_RANGE_M[0]) | (heights > PERSON_RANGE_M[1])).sum())

    errors, head_errors, foot_errors = track_height_errors(labels, by_frame, persons)
    result.matched = len(errors)
    if errors:
        result.median_error_m = float(np.median(errors))
        result.within = float(np.mean(np.array(errors) <= WITHIN_M))
    if head_errors:
        result.head_px = float(np.median(head_errors))
    if foot_errors:
        result.foot_px = float(np.median(foot_errors))
    result.identity = identity_scores(labels, by_frame)
    result.uncovered = uncovered_breakdown(labels, by_frame)
    return result


def track_height_errors(labels: dict[int, list[LabelledPerson]], by_frame: dict[int, list[dict]],
                        persons: dict[int, float]) -> tuple[list[float], list[float], list[float]]:
    """Each person track's final height error against the labelled person it covers most often
    (IoU >= ``MATCH_IOU``), and the pixel errors of its boxes' head-top and foot points."""
    from stages.association import iou_matrix

    votes: dict[int, dict[int, int]] = {}
    truth: dict[int, float] = {}
    head_errors, foot_errors = [], []
    for frame, rows in by_frame.items():
        people = labels.get(frame, [])
        for row in rows:
            if int(row["track_id"]) not in persons:
                continue
            x, y, w, h = (float(row[k]) for k in ("x", "y", "w", "h"))
            ious = iou_matrix([(x, y, w, h)], [p.box for p in people])[0]
            if not ious.size or ious.max() < MATCH_IOU:
                continue
            person = people[int(np.argmax(ious))]
            votes.setdefault(int(row["track_id"]), {}).setdefault(person.person, 0)
            votes[int(row["track_id"])][person.person] += 1
            truth[person.person] = person.height_m
            head_errors.append(np.hypot(x + w / 2 - person.head[0], y - person.head[1]))
            if person.foot_inside:
                foot_errors.append(np.hypot(x + w / 2 - person.foot[0], y + h - person.foot[1]))
    errors = []
    for tid, counts in votes.items():
        person = max(counts, key=counts.get)
        if np.isfinite(persons[tid]):
            errors.append(abs(persons[tid] - truth[person]))
    return errors, head_errors, foot_errors


def identity_scores(labels: dict[int, list[LabelledPerson]],
                    by_frame: dict[int, list[dict]]) -> IdentityScores:
    """Labelled people against every confirmed track box of the run (any class: a walker the run
    classed "other" is still followed), matched one-to-one per frame as ``eval-tracks`` matches
    (IoU >= 0.5)."""
    from scipy.optimize import linear_sum_assignment

    from pipeline.eval_metrics import matched_at_iou

    together: dict[tuple[int, str], int] = {}
    followed: dict[int, list[tuple[int, str]]] = {}
    frames_of: dict[int, int] = {}
    for frame, people in labels.items():
        for person in people:
            frames_of[person.person] = frames_of.get(person.person, 0) + 1
        rows = by_frame.get(frame, [])
        if not people or not rows:
            continue
        for i, j in matched_at_iou([p.box for p in people], [tuple(float(r[k]) for k in "xywh") for r in rows]):
            key = (people[i].person, rows[j]["track_id"])
            together[key] = together.get(key, 0) + 1
            followed.setdefault(people[i].person, []).append((frame, rows[j]["track_id"]))
    people_ids = sorted(frames_of)
    track_ids = sorted({t for _, t in together})
    id_tp = 0
    if track_ids:
        counts = np.array([[together.get((p, t), 0) for t in track_ids] for p in people_ids])
        people_index, track_index = linear_sum_assignment(-counts)   # one track id per person
        id_tp = int(counts[people_index, track_index].sum())
    switches = sum(sum(a[1] != b[1] for a, b in zip(seq, seq[1:]))
                   for seq in (sorted(v) for v in followed.values()))
    total = sum(frames_of.values())
    return IdentityScores(
        person_frames=total,
        covered=sum(together.values()) / max(total, 1),
        id_recall=id_tp / max(total, 1),
        id_switches=int(switches),
        mostly_tracked=sum(len(followed.get(p, [])) >= MOSTLY_TRACKED * frames_of[p] for p in people_ids),
        people=len(people_ids))


def uncovered_breakdown(labels: dict[int, list[LabelledPerson]],
                        by_frame: dict[int, list[dict]]) -> dict[str, int]:
    """Labelled person-frames by what covers them (``UNCOVERED_KINDS``), against every confirmed
    track box as :func:`identity_scores` matches them.

    Not covered, a person is under a box holding several people when the best-overlapping track
    box (IoU at least ``miss_near_iou``) covers ``miss_cover_share`` of two or more labelled
    people, as ``heightpipe eval-tracks --misses`` tells merged boxes; else that box is off, named
    by its edge furthest inside or outside the person's, as a share of the person's height: its
    bottom above the feet, its top below the crown, or a side.
    """
    from pipeline.eval_metrics import CONSTANTS as MISS, holds_several, matched_at_iou
    from stages.association import iou_matrix

    counts = dict.fromkeys(UNCOVERED_KINDS, 0)
    for frame, people in labels.items():
        boxes = [tuple(float(r[k]) for k in "xywh") for r in by_frame.get(frame, [])]
        bodies = [p.box for p in people]
        covered = {i for i, _ in matched_at_iou(bodies, boxes)} if boxes else set()
        near = iou_matrix(bodies, boxes) if boxes else np.zeros((len(people), 0))
        for i, person in enumerate(people):
            best = int(np.argmax(near[i])) if near.shape[1] else -1
            if i in covered:
                kind = "covered"
            elif best < 0 or near[i, best] < MISS.miss_near_iou:
                kind = "no track box near"
            elif holds_several(bodies, boxes[best]):
                kind = "under a box holding several"
            else:
                kind = _off_edge(person.box, boxes[best])
            counts[kind] += 1
    return counts


def _off_edge(label, box) -> str:
    """Which edge of ``box`` is furthest off the labelled body box (x, y, w, h each)."""
    x, y, w, h = label
    bx, by, bw, bh = box
    feet = (y + h) - (by + bh)                 # > 0: the box ends above the feet
    crown = by - y                             # > 0: the box starts below the crown
    side = max(abs(bx - x), abs((bx + bw) - (x + w)))
    largest = max(feet, crown, side)
    return ("box short of the feet" if largest == feet else
            "box short of the crown" if largest == crown else "box off to a side")


def run_mode(mode: str, out: Path, overrides: list[str]) -> ModeResult:
    prefix = out / mode
    base = [sys.executable, "-m", "pipeline.cli"]
    args = ["--set", "output.progress=false"] + [a for o in overrides for a in ("--set", o)]
    if mode == "calibration":
        args += ["--calibration", str(CALIBRATION)]
    elif mode == "camera-height":
        args += ["--camera-height", str(CAMERA_HEIGHT_M)]
    elif mode in ("self", "scene"):
        snippet = out / f"{mode}_calibration.toml"
        known = (["--calibration", str(CALIBRATION)] if mode == "self"
                 else ["--camera-height", str(CAMERA_HEIGHT_M)])
        done = subprocess.run(base + ["calibrate", str(VIDEO), *known, "--no-progress", *args[2:]],
                              capture_output=True, text=True)
        if done.returncode != 0:
            return ModeResult(mode, note=(done.stderr.strip().splitlines() or ["failed"])[-1])
        snippet.write_text(done.stdout)
        args += ["--config", str(snippet)]
    done = subprocess.run(base + ["run", str(VIDEO), "--out", str(prefix), *args],
                          capture_output=True, text=True)
    if done.returncode != 0:
        return ModeResult(mode, note=(done.stderr.strip().splitlines() or ["failed"])[-1])
    result = score(mode, prefix.with_name(mode + ".tracks.csv"), undistorted=mode not in ("camera-height", "scene"))
    result.note = next((line.strip() for line in done.stdout.splitlines() if "camera:" in line), "")
    return result


def draw_frame(tracks_csv: Path, frame_index: int, out: Path) -> None:
    """One undistorted frame of a calibrated run: person tracks with their heights, labelled points.

    Green boxes are people inside 1.5-2.1 m, red ones outside, grey ones without a height; the
    labelled head-top and foot points are white crosses.
    """
    import cv2

    from stages.calibration import load_calibration
    from stages.undistortion import Undistorter

    capture = cv2.VideoCapture(str(VIDEO))
    capture.set(cv2.CAP_PROP_POS_FRAMES, frame_index)
    ok, image = capture.read()
    capture.release()
    if not ok:
        raise SystemExit(f"bench.real_heights: cannot read frame {frame_index} of {VIDEO}")
    image = Undistorter(load_calibration(CALIBRATION)).undistort(image)
    for person in load_labels(undistort=True).get(frame_index, []):
        for u, v in (person.head, person.foot):
            cv2.drawMarker(image, (int(u), int(v)), (255, 255, 255), cv2.MARKER_CROSS, 18, 2)
    for row in read_tracks(tracks_csv).get(frame_index, []):
        if row["class"] != "person":
            continue
        x, y, w, h = (int(float(row[k])) for k in ("x", "y", "w", "h"))
        height = float(row["height_m"])
        inside = PERSON_RANGE_M[0] <= height <= PERSON_RANGE_M[1]
        colour = (128, 128, 128) if not np.isfinite(height) else (0, 200, 0) if inside else (0, 0, 255)
        cv2.rectangle(image, (x, y), (x + w, y + h), colour, 3)
        text = "no height" if not np.isfinite(height) else f"{height:.2f} m {row['height_source']}"
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 1.1, 2)
        ty = max(y - 10, th + 10)
        cv2.rectangle(image, (x, ty - th - 8), (x + tw + 8, ty + 6), (0, 0, 0), -1)
        cv2.putText(image, text, (x + 4, ty), cv2.FONT_HERSHEY_SIMPLEX, 1.1, colour, 2)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), cv2.resize(image, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))


def format_table(results: list[ModeResult]) -> str:
    lines = ["| mode | person tracks | mean (m) | min-max (m) | outside 1.5-2.1 | matched | median error (cm) | "
             f"within {100 * WITHIN_M:g} cm | head px | foot px | covered | IDR | ID switches | mostly tracked | "
             "note |",
             "|---" * 15 + "|"]
    for r in results:
        i = r.identity
        tracking = ("| - | - | - | - " if i is None else
                    f"| {i.covered:.3f} | {i.id_recall:.3f} | {i.id_switches} | {i.mostly_tracked}/{i.people} ")
        lines.append(f"| {r.mode} | {r.persons} | {r.mean_m:.3f} | {r.min_m:.2f}-{r.max_m:.2f} | "
                     f"{r.outside} | {r.matched} | {100 * r.median_error_m:.1f} | {r.within:.2f} | "
                     f"{r.head_px:.1f} | {r.foot_px:.1f} {tracking}| {r.note} |")
    return "\n".join(lines)


def format_uncovered(results: list[ModeResult]) -> str:
    """Shares of the labelled person-frames by ``UNCOVERED_KINDS``, one row per mode."""
    lines = ["| mode | " + " | ".join(UNCOVERED_KINDS) + " | person-frames |",
             "|---" * (len(UNCOVERED_KINDS) + 2) + "|"]
    for r in results:
        if r.uncovered is None:
            continue
        total = max(sum(r.uncovered.values()), 1)
        lines.append(f"| {r.mode} | " + " | ".join(f"{r.uncovered[k] / total:.3f}" for k in UNCOVERED_KINDS)
                     + f" | {sum(r.uncovered.values())} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", default=",".join(MODES))
    parser.add_argument("--out", default="runs/real_heights", type=Path)
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="config override for every run (repeatable)")
    parser.add_argument("--picture", type=Path, metavar="IMAGE",
                        help="also draw one frame of the calibration-mode run (tracks, heights, labels)")
    parser.add_argument("--picture-frame", type=int, default=60)
    parser.add_argument("--misses", action="store_true",
                        help="also what lies over the labelled person-frames no track box covers")
    args = parser.parse_args()
    if not VIDEO.is_file():
        print(f"bench.real_heights: {VIDEO} not found", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    results = [run_mode(mode, args.out, args.set) for mode in args.modes.split(",")]
    if args.picture and "calibration" in args.modes.split(","):
        draw_frame(args.out / "calibration.tracks.csv", args.picture_frame, args.picture)
    table = format_table(results)
    if args.misses:
        table += "\n\nLabelled person-frames by what covers them (shares):\n\n" + format_uncovered(results)
    (args.out / "table.md").write_text(table + "\n")
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
