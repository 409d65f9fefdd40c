"""drape.geometry.character_space.frames_at: reading per-frame values at fractional frames, against numpy's
np.interp per column (an independent formulation), clamped at both ends."""

import numpy as np

from drape.geometry.character_space import frames_at


def test_frames_at_is_np_interp_per_column_and_holds_the_ends():
    values = np.random.default_rng(0).normal(size=(7, 4, 3))
    at = np.array([[-1.5, 0.0, 0.25], [3.5, 6.0, 9.0]])  # before the first frame, between, past the last
    got = frames_at(values, at)
    assert got.shape == (2, 3, 4, 3)
    flat = values.reshape(7, -1)
    want = np.stack([np.interp(at.ravel(), np.arange(7), flat[:, k]) for k in range(flat.shape[1])], -1)
    assert np.allclose(got.reshape(-1, 12), want, atol=1e-12)
    assert np.array_equal(frames_at(values, np.arange(7.0)), values)  # whole frames: the values themselves
