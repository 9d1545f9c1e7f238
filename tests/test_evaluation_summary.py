"""`summarize`, the per-episode statistics of an evaluation record, on hand-made samples with known answers (apart
from test_evaluation, which trains agents)."""

import math

import numpy as np
import pytest

from angora_jax.experiment.evaluation import summarize


def test_summary_of_a_hand_made_sample():
    # Sorted: 1 2 2 2 4 4 9. The sum is 24 and the sum of squares 126, so the squared deviations from the mean sum
    # to 126 - 24^2 / 7 = 306 / 7 and the variance (ddof 1) is 51 / 7.
    summary = summarize(np.array([4, 1, 2, 9, 2, 4, 2]))
    assert summary == pytest.approx({"mean": 24 / 7, "median": 2.0, "mode": 2.0, "std": math.sqrt(51 / 7),
                                     "stderr": math.sqrt(51 / 7 / 7), "min": 1.0, "max": 9.0})


def test_mode_is_the_most_frequent_value_and_the_smallest_among_ties():
    assert summarize(np.array([5, 3, 7, 3, 5, 8, 5]))["mode"] == 5.0
    assert summarize(np.array([3, 3, 1, 1, 5]))["mode"] == 1.0
    assert summarize(np.array([0.5, 9.0, 0.25]))["mode"] == 0.25  # all once: the smallest


def test_a_single_episode_has_no_spread():
    assert summarize(np.array([7.0])) == {"mean": 7.0, "median": 7.0, "mode": 7.0, "std": 0.0, "stderr": 0.0,
                                          "min": 7.0, "max": 7.0}
