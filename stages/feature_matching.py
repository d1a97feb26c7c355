"""Feature matching between consecutive frames: ORB keypoints followed by pyramidal LK flow.

Points are ORB corners of the previous frame, tracked into this frame with Lucas-Kanade
and kept only if (a) tracking back lands where they started and (b) the ORB descriptor at
the new position still matches. Background points then give the camera's own motion (a
RANSAC similarity, as BoT-SORT does for shake); points on above-ground regions are the
ones the tracker uses for association votes and the height-consistency check.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from core.config import GroundConfig, MatchingConfig
from core.packets import FeatureMatches, FrameKeypoints, FramePacket


@dataclass(frozen=True)
class FeatureMatchingConstants:
    """Feature matching's fixed numbers: properties of the method, not of a camera or a
    scene (those are in ``[matching]``; the rule is in docs/design.md, Configuration)."""

    # A point tracked forward and back again must land within this of where it started (LK's
    # forward-backward check): a point that drifts further was not one texture in both frames.
    forward_backward_max_px: float = 1.0
    # Share of the ORB budget spent on above-ground regions: movers are small but matter most.
    object_feature_share: float = 0.5
    # Four pyramid levels instead of ORB's eight: consecutive frames barely change scale, and the
    # coarse levels cost time for corners LK cannot use anyway.
    orb_levels: int = 4
    # Fewer background points than this: the background is hidden (a bus filling the view) and
    # RANSAC would fit a few shadow or mismatch points (generator: a 300 px "shake" at 6 points that
    # threw every track off its object). The camera is then taken to be still.
    min_background_points: int = 12
    # The camera is fixed: a motion is accepted only if, within this tolerance (pixels of the
    # matching image), it explains clearly more background points than standing still does
    # (still points at least this share of the motion's: the camera is taken to be still). A
    # vehicle's shadow creeping over the ground fitted 2 px "shakes" at RANSAC's 3 px tolerance.
    still_tolerance_px: float = 1.0
    still_preference: float = 0.9


CONSTANTS = FeatureMatchingConstants()


class KeypointDetector:
    """Each frame's ORB keypoints on its matching image (``packet.keypoints``).

    A stage apart from the matching that uses them because it needs this frame's height map but
    not the last frame: the overlapped run finds them on the network's thread, right after the
    network, and matches on the calling thread, which has more to do (docs/design.md, Threads
    and processes). ORB draws no random numbers, so where it runs changes nothing.
    """

    def __init__(self, config: MatchingConfig, ground: GroundConfig):
        self.config = config
        self.height_threshold_m = ground.height_threshold_m
        self.orb_scene = cv2.ORB_create(nfeatures=int(config.orb_features * (1 - CONSTANTS.object_feature_share)),
                                        nlevels=CONSTANTS.orb_levels)
        self.orb_objects = cv2.ORB_create(nfeatures=int(config.orb_features * CONSTANTS.object_feature_share),
                                          nlevels=CONSTANTS.orb_levels)

    def process(self, packet: FramePacket) -> FramePacket:
        packet.keypoints = self.find(packet)
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""

    def find(self, packet: FramePacket) -> FrameKeypoints:
        """The frame's matching image, its above-ground mask and its keypoints there."""
        gray = cv2.cvtColor(packet.frame.image, cv2.COLOR_BGR2GRAY)
        scale = self.downscale(gray.shape[1])
        if scale > 1:
            gray = cv2.resize(gray, (gray.shape[1] // scale, gray.shape[0] // scale), interpolation=cv2.INTER_AREA)
        above_ground = self._above_ground(packet, gray.shape[::-1])
        keypoints, descriptors = self._detect(gray, above_ground)
        return FrameKeypoints(gray, scale, above_ground, keypoints, descriptors)

    def downscale(self, width: int) -> int:
        """The matching image is 1/N of a frame ``width`` wide: ``downscale``, or more where the
        frame is wider than ``max_width`` times it (the window and ORB's budget are sized for the
        matching image, not for the source)."""
        scale = max(1, self.config.downscale)
        if self.config.max_width > 0:
            scale = max(scale, -(-width // self.config.max_width))
        return scale

    def _detect(self, gray: np.ndarray, above_ground: np.ndarray | None) -> tuple[list, np.ndarray | None]:
        if above_ground is None:
            keypoints, descriptors = self.orb_scene.detectAndCompute(gray, None)
            return list(keypoints), descriptors
        object_mask = above_ground.astype(np.uint8) * 255
        kp_obj, des_obj = self.orb_objects.detectAndCompute(gray, object_mask)
        kp_bg, des_bg = self.orb_scene.detectAndCompute(gray, cv2.bitwise_not(object_mask))
        keypoints = list(kp_obj) + list(kp_bg)
        parts = [d for d in (des_obj, des_bg) if d is not None]
        return keypoints, (np.vstack(parts) if parts else None)

    def _above_ground(self, packet: FramePacket, size: tuple[int, int]) -> np.ndarray | None:
        """Pixels above the ground at the matching image's ``size`` (nearest source pixel).

        The height map is sampled down before it is thresholded, not after: the same pixels
        (nearest-neighbour picks one source pixel either way), one comparison per matching pixel
        instead of per source pixel (1920x1080: 0.9 -> 0.45 ms).
        """
        if packet.height_map is None:
            return None
        heights = packet.height_map
        if heights.shape[::-1] != size:
            heights = cv2.resize(heights, size, interpolation=cv2.INTER_NEAREST)
        return heights > self.height_threshold_m


class FeatureMatcher:
    """``packet.matches``: the last frame's keypoints tracked into this frame. Uses the keypoints
    stage's ``packet.keypoints``, or finds them itself where no such stage ran (a chain without
    it, a live frame that reused the last network outputs)."""

    def __init__(self, config: MatchingConfig, ground: GroundConfig):
        self.config = config
        self.detector = KeypointDetector(config, ground)
        self.orb_describe = cv2.ORB_create(nlevels=CONSTANTS.orb_levels)
        self.lk_params = dict(winSize=(config.lk_window, config.lk_window), maxLevel=config.lk_levels,
                              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
        self._previous: FrameKeypoints | None = None

    def process(self, packet: FramePacket) -> FramePacket:
        current = packet.keypoints if packet.keypoints is not None else self.detector.find(packet)
        previous = self._previous
        if previous is not None and previous.keypoints and previous.gray.shape == current.gray.shape:
            packet.matches = self._match(previous, current)
            if current.scale > 1:
                packet.matches = self._to_source_pixels(packet.matches, current.scale)
        self._previous = current
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""

    def _match(self, previous: FrameKeypoints, current: FrameKeypoints) -> FeatureMatches:
        prev = np.float32([kp.pt for kp in previous.keypoints]).reshape(-1, 1, 2)
        curr, status, _ = cv2.calcOpticalFlowPyrLK(previous.gray, current.gray, prev, None, **self.lk_params)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(current.gray, previous.gray, curr, None, **self.lk_params)
        fb_error = np.linalg.norm((back - prev).reshape(-1, 2), axis=1)
        keep = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb_error < CONSTANTS.forward_backward_max_px)
        keep &= self._descriptors_agree(previous, current.gray, curr.reshape(-1, 2), keep)
        prev_pts = prev.reshape(-1, 2)[keep]
        curr_pts = curr.reshape(-1, 2)[keep]
        on_object = self._on_object(curr_pts, current.above_ground)
        motion, inliers = self._camera_motion(prev_pts[~on_object], curr_pts[~on_object])
        # Background points that disagree with the camera motion are mismatches: drop them.
        keep_bg = np.ones(len(prev_pts), bool)
        keep_bg[np.flatnonzero(~on_object)] = inliers
        return FeatureMatches(prev_pts=prev_pts[keep_bg], curr_pts=curr_pts[keep_bg],
                              on_object=on_object[keep_bg], camera_motion=motion)

    @staticmethod
    def _to_source_pixels(matches: FeatureMatches, scale: int) -> FeatureMatches:
        """Matching ran on a 1/scale image: points and the motion's translation scale back."""
        motion = matches.camera_motion.copy()
        motion[:, 2] *= scale
        # pixel centres: (x + 0.5) * s - 0.5
        offset = (scale - 1) / 2.0
        return FeatureMatches(prev_pts=matches.prev_pts * scale + offset,
                              curr_pts=matches.curr_pts * scale + offset,
                              on_object=matches.on_object, camera_motion=motion)

    def _descriptors_agree(self, previous: FrameKeypoints, gray: np.ndarray, curr: np.ndarray,
                           candidates: np.ndarray) -> np.ndarray:
        """ORB check: the descriptor at the tracked position must still match the original."""
        agree = np.zeros(len(curr), bool)
        if previous.descriptors is None:
            return agree
        idx = np.flatnonzero(candidates)
        moved = [cv2.KeyPoint(float(curr[i, 0]), float(curr[i, 1]), previous.keypoints[i].size,
                              previous.keypoints[i].angle, 0, previous.keypoints[i].octave, int(i))
                 for i in idx]
        moved, descriptors = self.orb_describe.compute(gray, moved)
        if descriptors is None:
            return agree
        original = np.array([kp.class_id for kp in moved])
        distance = np.unpackbits(descriptors ^ previous.descriptors[original], axis=1).sum(axis=1)
        agree[original[distance <= self.config.max_hamming]] = True
        return agree

    @staticmethod
    def _on_object(points: np.ndarray, above_ground: np.ndarray | None) -> np.ndarray:
        if above_ground is None or len(points) == 0:
            return np.zeros(len(points), bool)
        h, w = above_ground.shape
        x = np.clip(points[:, 0].round().astype(int), 0, w - 1)
        y = np.clip(points[:, 1].round().astype(int), 0, h - 1)
        return above_ground[y, x]

    def _camera_motion(self, prev_pts: np.ndarray, curr_pts: np.ndarray):
        """Similarity transform of the static background; identity unless it clearly does better.

        Returns the 2x3 motion and which background points agree with it.
        """
        identity = np.eye(2, 3, dtype=np.float32)
        threshold = self.config.ransac_threshold_px
        moved = np.linalg.norm(curr_pts - prev_pts, axis=1)
        if len(prev_pts) < CONSTANTS.min_background_points:
            return identity, moved <= threshold
        matrix, inliers = cv2.estimateAffinePartial2D(
            prev_pts, curr_pts, method=cv2.RANSAC, ransacReprojThreshold=threshold)
        if matrix is None:
            return identity, moved <= threshold
        tolerance = min(threshold, CONSTANTS.still_tolerance_px)
        residual = np.linalg.norm(prev_pts @ matrix[:, :2].T + matrix[:, 2] - curr_pts, axis=1)
        if (moved <= tolerance).sum() >= CONSTANTS.still_preference * (residual <= tolerance).sum():
            return identity, moved <= threshold
        return matrix.astype(np.float32), inliers.ravel().astype(bool)
