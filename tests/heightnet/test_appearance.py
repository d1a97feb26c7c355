"""Appearance randomisation: off means untouched (and the same random stream), on means a
changed look with labels' geometry kept and the pair's two frames changed alike."""

import dataclasses

import numpy as np

from heightnet.appearance import AppearanceDraw, apply_appearance, draw_appearance, pair_texture


def _image(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = np.full((48, 64, 3), 90, np.uint8)
    image[10:40, 20:30] = rng.integers(0, 255, 3, dtype=np.uint8)   # a flat-coloured "walker"
    return image


def test_off_draws_nothing_and_leaves_the_random_stream_as_it_was():
    rng, untouched = np.random.default_rng(3), np.random.default_rng(3)
    assert draw_appearance(rng, 0.0) == AppearanceDraw()
    assert rng.random() == untouched.random()
    image = _image()
    assert apply_appearance(image, AppearanceDraw(), rng) is image


def test_every_change_keeps_the_size_and_type_and_changes_the_look():
    image = _image()
    changes = {"gamma": 1.5, "channel_order": (2, 0, 1), "grey": True, "blur_sigma": 1.0,
               "sharpen": 0.8, "texture_sigma": 8.0, "noise_sigma": 4.0, "rescale": 0.5,
               "jpeg_quality": 20}
    for field, value in changes.items():
        draw = dataclasses.replace(AppearanceDraw(), **{field: value})
        rng = np.random.default_rng(0)
        out = apply_appearance(image, draw, rng, pair_texture(rng, draw, 64, 48))
        assert out.shape == image.shape and out.dtype == np.uint8, field
        assert np.abs(out.astype(int) - image).max() > 0, field


def test_both_frames_of_a_pair_change_alike_but_for_sensor_noise():
    image = _image()
    rng = np.random.default_rng(1)
    draw = dataclasses.replace(draw_appearance(rng, 1.0), noise_sigma=0.0, texture_sigma=6.0)
    texture = pair_texture(rng, draw, 64, 48)
    first = apply_appearance(image, draw, rng, texture)
    second = apply_appearance(image, draw, rng, texture)
    assert np.array_equal(first, second)
    noisy = dataclasses.replace(draw, noise_sigma=5.0)
    assert not np.array_equal(apply_appearance(image, noisy, rng, texture),
                              apply_appearance(image, noisy, rng, texture))


def test_the_share_of_randomised_pairs_follows_the_probability():
    rng = np.random.default_rng(7)
    changed = sum(draw_appearance(rng, 0.6) != AppearanceDraw() for _ in range(2000))
    assert 0.5 < changed / 2000 < 0.62
