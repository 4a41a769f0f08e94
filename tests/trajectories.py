"""Synthetic trajectory-correlated data for the shift tests (tests/test_shift*.py)."""

from __future__ import annotations

import numpy as np


def ar1_episodes(episodes: int, seed: int, shift: float = 0.0, length: int = 50, d: int = 24
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Episodes of a trajectory-correlated process (like a policy's rollouts): per episode a centre
    ~ N(0, 0.25 I) plus an AR(1) walk with autocorrelation 0.98, every state moved by ``shift`` on each
    axis; and each row's episode id."""
    rng = np.random.default_rng(seed)
    centre = 0.5 * rng.standard_normal((episodes, d))
    state = rng.standard_normal((episodes, d))
    out = np.empty((episodes, length, d), dtype=np.float32)
    for t in range(length):
        out[:, t] = centre + state + shift
        state = 0.98 * state + np.sqrt(1 - 0.98 ** 2) * rng.standard_normal((episodes, d))
    return out.reshape(-1, d), np.repeat(np.arange(episodes), length)
