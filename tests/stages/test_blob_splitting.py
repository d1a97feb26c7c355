"""Splitting merged blobs: by height peaks, by foreground pieces, by a row of heads."""

from __future__ import annotations

import numpy as np

from stages.blob_splitting import split_by_foreground, split_by_heads, split_by_height_peaks


def test_merged_blob_splits_at_separate_height_peaks():
    blob = np.zeros((60, 50), bool)
    blob[:, 5:45] = True                                   # one foreground blob, two people wide
    heights = np.zeros((60, 50), np.float32)
    heights[:, 5:24] = np.linspace(1.6, 0.05, 60)[:, None]
    heights[:, 26:45] = np.linspace(1.9, 0.05, 60)[:, None]
    heights[40:, 24:26] = 0.3                              # legs touching low down
    pieces = split_by_height_peaks(blob, heights, min_area=40)
    assert len(pieces) == 2
    tops = sorted(round(float(heights[p].max()), 1) for p in pieces)
    assert tops == [1.6, 1.9]
    single = np.zeros((60, 20), np.float32) + np.linspace(1.7, 0.05, 60)[:, None]
    assert len(split_by_height_peaks(np.ones((60, 20), bool), single, min_area=40)) == 1


def test_people_side_by_side_split_on_their_foreground():
    """The grown blob bridges the gap between two walkers; their own foreground does not."""
    blob = np.zeros((60, 50), bool)
    blob[:, 3:47] = True
    moving = np.zeros_like(blob)
    moving[2:58, 6:22] = True                              # left person
    moving[0:60, 26:44] = True                             # right person, four columns apart
    moving[30:34, 4:6] = True                              # a hand: too small to seed anything
    pieces = split_by_foreground(blob, moving, min_area=40)
    assert len(pieces) == 2
    left, right = sorted(pieces, key=lambda p: np.nonzero(p)[1].mean())
    assert left[:, 6:22].all() and not left[:, 26:44].any()
    assert right[:, 26:44].all() and not right[:, 6:22].any()
    assert (left | right).sum() == blob.sum()              # every blob pixel goes to one of them


def test_one_persons_stacked_fragments_and_a_car_stay_whole():
    blob = np.ones((60, 20), bool)
    coat_missed = np.zeros_like(blob)
    coat_missed[0:12, 6:14] = True                         # head and shoulders
    coat_missed[35:60, 4:16] = True                        # legs: the plain coat between is not foreground
    assert len(split_by_foreground(blob, coat_missed, min_area=40)) == 1

    car = np.ones((30, 90), bool)
    halves = np.zeros_like(car)
    halves[2:30, 2:40] = True                              # front and back of a car, wider than tall
    halves[2:30, 48:88] = True
    assert len(split_by_foreground(car, halves, min_area=40)) == 1


def _person_shape(h: int = 24, w: int = 8) -> np.ndarray:
    """A blocky walker: shoulders at a sixth of the height, a head a third as wide."""
    shape = np.zeros((h, w), bool)
    shape[h // 6:, :] = True
    shape[:h // 6, w // 2 - w // 6:w // 2 + w // 6 + 1] = True
    return shape


def test_a_group_walking_shoulder_to_shoulder_splits_at_its_heads():
    group = np.hstack([_person_shape(), _person_shape(), _person_shape()])
    pieces = split_by_heads(group, group, min_area=20)
    assert [tuple(np.flatnonzero(p.any(axis=0))[[0, -1]]) for p in pieces] == [(0, 7), (8, 15), (16, 23)]


def test_a_car_a_lone_walker_and_a_low_dip_stay_whole():
    car = np.zeros((14, 30), bool)
    car[6:, :], car[:6, 8:22] = True, True                     # a cabin: one flat peak
    assert len(split_by_heads(car, car, min_area=20)) == 1
    walker = _person_shape()
    assert len(split_by_heads(walker, walker, min_area=20)) == 1
    bumps = np.ones((24, 24), bool)
    bumps[0, 8:16] = False                                     # a one-row dip: not two heads
    assert len(split_by_heads(bumps, bumps, min_area=20)) == 1


def test_a_blob_taller_than_a_person_is_no_row_of_heads():
    """A dark bus passing dark windows loses its roof's foreground in patches: its outline dips
    like a group's, but a blob whose columns stand higher than a person is not cut at them."""
    group = np.hstack([_person_shape(), _person_shape(), _person_shape()])
    people = np.where(group, 1.7, 0.0)
    assert len(split_by_heads(group, group, min_area=20, heights=people)) == 3
    bus = np.where(group, 3.4, 0.0)
    assert len(split_by_heads(group, group, min_area=20, heights=bus)) == 1
