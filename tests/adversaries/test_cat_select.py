"""CAT selection's helpers at their edges (issue 24: each test here kills mutants of `seal.adversaries.cat.select`
that the generator tests let live): invalid-row filling, the smoothed heading at the track ends and at the chord
threshold, the prior's softmax with large scores, and roll-outs shorter than the candidates."""

from __future__ import annotations

import numpy as np
import pytest

from seal.adversaries.cat.select import _fill_invalid, cat_select, flattened_prior, smoothed_heading
from seal.core.scenario import CURRENT_STEP, N_FUTURE

SIZE = (4.5, 2.0)


def test_fill_invalid_takes_the_earlier_valid_row_else_the_next() -> None:
    valid = np.array([[False, True, False, False, True, False],
                      [True, False, False, False, False, True],
                      [False, False, False, False, False, False],
                      [False, False, False, False, True, False]])
    xy = np.stack([np.arange(6.0)[None].repeat(4, 0), 10 * np.arange(4.0)[:, None].repeat(6, 1)], axis=-1)
    filled = _fill_invalid(xy, valid)
    assert filled[0, :, 0].tolist() == [1, 1, 1, 1, 4, 4]  # leading gap from the next, the rest from the earlier
    assert filled[1, :, 0].tolist() == [0, 0, 0, 0, 0, 5]
    assert filled[2, :, 0].tolist() == [5, 5, 5, 5, 5, 5]  # nothing valid: the last row
    assert filled[3, :, 0].tolist() == [4, 4, 4, 4, 4, 4]  # a long leading gap: still the first valid row
    np.testing.assert_array_equal(filled[..., 1], xy[..., 1])  # rows stay rows


def _circle(n: int, radius: float = 20.0, step_rad: float = 0.1) -> np.ndarray:
    angle = step_rad * np.arange(n)
    return np.stack([radius * np.sin(angle), radius * (1 - np.cos(angle))], axis=-1)[None]  # counter-clockwise


def _chord_heading(xy: np.ndarray, lo: int, hi: int) -> float:
    d = xy[0, hi] - xy[0, lo]
    return float(np.arctan2(d[1], d[0]))


def test_smoothed_heading_clips_the_chord_at_both_ends() -> None:
    """On a curve every chord has its own direction: the window is +-2 rows by default, clipped to the track."""
    xy = _circle(10)
    heading = np.full((1, 10), 9.0)  # never used: every chord is long enough
    rows = np.array([0, 1, 5, 8, 9])
    got = smoothed_heading(xy, heading, rows)[0]
    expected = [_chord_heading(xy, 0, 2), _chord_heading(xy, 0, 3), _chord_heading(xy, 3, 7),
                _chord_heading(xy, 6, 9), _chord_heading(xy, 7, 9)]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def test_smoothed_heading_falls_back_on_short_chords_only() -> None:
    """A straight run along x at 0.25 m per row: a 1 m chord meets a 1 m threshold (heading 0); a still vehicle
    keeps its own heading at that row, first and last rows included. The default threshold (0.2 m) is met by a
    0.4 m chord."""
    moving = np.stack([0.25 * np.arange(8), np.zeros(8)], axis=-1)[None]
    own = np.linspace(0.5, 1.2, 8)[None]
    rows = np.array([0, 3, 7])
    np.testing.assert_array_equal(smoothed_heading(moving, own, np.array([3]), min_chord_m=1.0)[0], [0.0])
    slow = np.stack([0.1 * np.arange(8), np.zeros(8)], axis=-1)[None]
    np.testing.assert_array_equal(smoothed_heading(slow, own, np.array([3]))[0], [0.0])
    still = np.zeros((1, 8, 2))
    np.testing.assert_array_equal(smoothed_heading(still, own, rows)[0], own[0, rows])


def test_flattened_prior_with_large_scores_and_with_exactly_n_kept_modes() -> None:
    p1 = flattened_prior(np.ones(2), logits=np.array([1000.0, 999.0]))
    np.testing.assert_allclose(p1, np.exp([1.0, 0.0]) / np.exp([1.0, 0.0]).sum(), rtol=1e-12)
    probs = np.array([0.4, 0.3, 0.2, 0.1])
    np.testing.assert_allclose(flattened_prior(probs, n_kept=4), probs, rtol=1e-12)


def _ego(n_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One ego roll-out standing at the origin for ``n_steps`` scenario steps."""
    return np.zeros((1, n_steps, 2)), np.zeros((1, n_steps)), np.ones((1, n_steps), dtype=bool)


def test_one_candidate_is_enough_and_none_is_an_error() -> None:
    cand = np.zeros((1, N_FUTURE, 2))
    sel = cat_select(cand, np.zeros((1, N_FUTURE)), np.ones(1), SIZE, *_ego(CURRENT_STEP + N_FUTURE + 1), SIZE)
    assert sel.index == 0 and sel.collided and sel.predicted_step == CURRENT_STEP + 5
    with pytest.raises(ValueError, match="needs candidates and roll-outs, got 0 candidates and 1 roll-outs"):
        cat_select(cand[:0], np.zeros((0, N_FUTURE)), np.ones(0), SIZE, *_ego(50), SIZE)


def test_a_short_roll_out_counts_only_its_own_steps() -> None:
    """The ego roll-out ends at scenario step 24 (25 rows): samples at steps 15 and 20 see it; the sample at
    step 25 (= its length) and later do not, even though its last position lies on the candidate's path."""
    cand = np.zeros((2, N_FUTURE, 2))
    cand[0, :, 0] = 100.0  # far away until ...
    cand[0, 14:, 0] = 0.0  # ... scenario step 25 (row 14), where it sits on the ego's last position
    cand[1, :, 0] = np.linspace(60.0, 30.0, N_FUTURE)  # never touches: the fallback's closest
    sel = cat_select(cand, np.zeros((2, N_FUTURE)), np.array([0.5, 0.5]), SIZE, *_ego(25), SIZE)
    assert sel.first_hit.tolist() == [[-1], [-1]] and not sel.collided
    assert sel.min_distance_m[0] == pytest.approx(100.0) and sel.index == 1
    assert sel.predicted_step == 20  # the last sample the roll-out covers


def test_a_colliding_candidate_whose_prior_underflows_still_wins() -> None:
    """P1 of the colliding candidate is exactly 0 (its logit is 1000 below): every score is 0, and the colliding
    candidate is chosen over the likelier one that never comes near, whatever the number of roll-outs."""
    cand = np.zeros((2, N_FUTURE, 2))
    cand[0, :, 0] = 500.0  # never near
    ego = tuple(np.repeat(a, 2, axis=0) for a in _ego(CURRENT_STEP + N_FUTURE + 1))  # two identical roll-outs
    sel = cat_select(cand, np.zeros((2, N_FUTURE)), np.ones(2), SIZE, *ego, SIZE, logits=np.array([0.0, -1000.0]))
    assert sel.p1[1] == 0.0 and sel.scores.max() == 0.0
    assert sel.index == 1 and sel.collided


def test_the_last_row_of_a_short_roll_out_is_its_own_position() -> None:
    """A roll-out of 21 rows (steps 0..20) jumps 50 m on its last step: the sample at step 20 sees the ego where
    it is at step 20, not one step earlier."""
    xy, heading, valid = _ego(21)
    xy[0, 20] = (50.0, 0.0)
    cand = np.zeros((1, N_FUTURE, 2))
    cand[0, :, 0] = 50.0  # waits where the ego arrives
    sel = cat_select(cand, np.zeros((1, N_FUTURE)), np.ones(1), SIZE, xy, heading, valid, SIZE)
    assert sel.collided and sel.first_hit.tolist() == [[1]] and sel.predicted_step == 20
