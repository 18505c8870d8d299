"""Cross-check of the car-following measures (`seal.scoring.social.following_per_step`: THW, TTC, DRAC).

(a) Hand-computed cases, always run: small hand-built pairs (one lane, lead braking, different lengths,
    heading difference, lane connectivity) against numbers worked out in the comments.
(b) An independent implementation, commonroad-crime 0.4.5, on the shared NGSIM US-101 recordings, per
    (follower, leader, step) sample. Optional: needs the `crosscheck` extra (``pip install -e '.[crosscheck]'``,
    ~1 GB) and skips without it or without the data folder. Run it with the table of agreement printed:
    ``python -m pytest --noconftest tests/scoring/test_following_crosscheck.py -s`` (``--noconftest``: the shared
    fixtures import the simulator, which a cross-check environment need not have). The definitions differ in
    documented ways (`crime_crosscheck` module docstring); the asserted tolerances follow from them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scoring_builders import straight_road, track

from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import DT_S
from seal.scoring.frenet import RoadIndex
from seal.scoring.social import TrackContext, following_per_step, social_features
from seal.scoring.tracks import AgentTracks, from_tracks

NGSIM = Path(__file__).resolve().parents[3] / "shared" / "data" / "ngsim-us101"
T_STEPS = 21  # 2 s at 10 Hz is enough for every hand case


def tracks_of(road: RoadDescription, *tracks: np.ndarray) -> tuple[AgentTracks, RoadIndex]:
    index = RoadIndex(road)
    return from_tracks(np.stack(tracks), index), index


def straight(x0: float, speed: float, y: float = 0.0, length: float = 4.5, accel: float = 0.0) -> np.ndarray:
    """``[T_STEPS, 8]`` track along +x from ``x0`` (m) at ``speed`` (m/s), constant ``accel`` (m/s^2).

    The velocity is given exactly (not finite differences), so the hand numbers hold at every step."""
    t = np.arange(T_STEPS) * DT_S
    x = x0 + speed * t + 0.5 * accel * t**2
    vel = np.stack([speed + accel * t, np.zeros(T_STEPS)], axis=1)
    return track(np.stack([x, np.full(T_STEPS, y)], axis=1), length=length, vel=vel)


def pair(a: AgentTracks, index: RoadIndex, i: int = 0, j: int = 1) -> dict[str, np.ndarray]:
    """Per-step measures ``[T]`` of the ordered pair (i, j) as times: THW, TTC (inf when not closing), DRAC."""
    st = following_per_step(a, a, np.array([i]), np.array([j]), index)
    if st.rows.size == 0:
        return {"ok": np.zeros(a.valid.shape[1], dtype=bool)}
    with np.errstate(divide="ignore"):
        return {
            "ok": st.ok[0], "j_leads": st.j_leads[0], "gap": st.gap[0], "thw": 1.0 / st.inv_thw[0],
            "ttc": 1.0 / st.inv_ttc[0], "drac": st.drac[0],
        }


# ------------------------------------------------------------------------------------------------ (a) by hand
def test_same_lane_constant_speeds() -> None:
    # Follower at x = 0 m, 20 m/s; leader 30 m ahead (centres), 15 m/s; both 4.5 m long.
    # Step 0: bumper gap 30 - 4.5 = 25.5 m; THW = 25.5 / 20 = 1.275 s; TTC = 25.5 / 5 = 5.1 s;
    # DRAC = 5^2 / (2 * 25.5) = 0.4902 m/s^2. Step 10 (1 s): gap 25.5 - 5 = 20.5 m; THW 1.025 s; TTC 4.1 s;
    # DRAC 25 / 41 = 0.6098 m/s^2.
    a, index = tracks_of(straight_road(), straight(0.0, 20.0), straight(30.0, 15.0))
    m = pair(a, index)
    assert m["ok"].all() and m["j_leads"].all()
    for step, gap, thw, ttc, drac in ((0, 25.5, 1.275, 5.1, 0.4902), (10, 20.5, 1.025, 4.1, 0.6098)):
        assert m["gap"][step] == pytest.approx(gap, abs=1e-4)
        assert m["thw"][step] == pytest.approx(thw, abs=1e-4)
        assert m["ttc"][step] == pytest.approx(ttc, abs=1e-4)
        assert m["drac"][step] == pytest.approx(drac, abs=1e-4)
    # The same pair seen from the leader: i leads, the follower is j; the measures are the pair's, unchanged.
    r = pair(a, index, 1, 0)
    assert not r["j_leads"].any()
    np.testing.assert_allclose(r["thw"], m["thw"], rtol=1e-12)
    np.testing.assert_allclose(r["ttc"], m["ttc"], rtol=1e-12)
    # Opening gap (leader faster, 20 vs 15 m/s): headway only. THW = 25.5 / 15 = 1.7 s, no TTC, DRAC 0.
    o, index = tracks_of(straight_road(), straight(0.0, 15.0), straight(30.0, 20.0))
    m = pair(o, index)
    assert m["thw"][0] == pytest.approx(1.7, abs=1e-4)
    assert np.isinf(m["ttc"]).all() and (m["drac"] == 0.0).all()


def test_lead_braking() -> None:
    # Both at 20 m/s, leader 40 m ahead brakes at 4 m/s^2 from t = 0: x_l = 40 + 20 t - 2 t^2, v_l = 20 - 4 t.
    # t = 0: gap 35.5 m, no closing: THW = 35.5 / 20 = 1.775 s, no TTC, DRAC 0.
    # t = 1 s: centres 58 - 20 = 38 m, gap 33.5 m, closing 4 m/s: THW 1.675 s, TTC 8.375 s, DRAC 16 / 67 = 0.2388.
    # t = 2 s: centres 72 - 40 = 32 m, gap 27.5 m, closing 8 m/s: THW 1.375 s, TTC 3.4375 s, DRAC 64 / 55 = 1.1636.
    a, index = tracks_of(straight_road(), straight(0.0, 20.0), straight(40.0, 20.0, accel=-4.0))
    m = pair(a, index)
    assert m["thw"][0] == pytest.approx(1.775, abs=1e-4)
    assert np.isinf(m["ttc"][0]) and m["drac"][0] == 0.0
    for step, thw, ttc, drac in ((10, 1.675, 8.375, 0.2388), (20, 1.375, 3.4375, 1.1636)):
        assert m["thw"][step] == pytest.approx(thw, abs=1e-4)
        assert m["ttc"][step] == pytest.approx(ttc, abs=1e-4)
        assert m["drac"][step] == pytest.approx(drac, abs=1e-4)


def test_different_lengths_and_overlap_floor() -> None:
    # A 4 m car at 25 m/s behind a 12 m truck at 20 m/s, centres 30 m apart: gap 30 - (2 + 6) = 22 m;
    # THW 22 / 25 = 0.88 s, TTC 22 / 5 = 4.4 s, DRAC 25 / 44 = 0.5682 m/s^2. A centre distance of 6 m is a gap of
    # -2 m (the boxes overlap): floored at 0.1 m, THW = 25 / 0.1 = 0.004 s.
    a, index = tracks_of(straight_road(), straight(0.0, 25.0, length=4.0), straight(30.0, 20.0, length=12.0))
    m = pair(a, index)
    assert (m["gap"][0], m["thw"][0], m["ttc"][0], m["drac"][0]) == pytest.approx((22.0, 0.88, 4.4, 0.5682), abs=1e-4)
    # Truck behind car: the same gap from the other lengths' halves.
    b, index = tracks_of(straight_road(), straight(0.0, 25.0, length=12.0), straight(30.0, 20.0, length=4.0))
    assert pair(b, index)["gap"][0] == pytest.approx(22.0, abs=1e-4)
    c, index = tracks_of(straight_road(), straight(0.0, 25.0, length=4.0), straight(6.0, 20.0, length=12.0))
    assert pair(c, index)["gap"][0] == pytest.approx(0.1)
    assert pair(c, index)["thw"][0] == pytest.approx(0.004, abs=1e-6)


@pytest.mark.parametrize(("angle_deg", "follows"), [(40.0, True), (50.0, False)])
def test_heading_difference_over_45_deg_excluded(angle_deg: float, follows: bool) -> None:
    # The leader, 30 m ahead on the lane centre, heads `angle_deg` off the lane (cutting across at 10 m/s). It
    # still projects onto the lane (candidate lanes are within 60 deg), but only headings within 45 deg of the
    # follower's count as following. At 40 deg: gap 25.5 m, THW 25.5 / 20 = 1.275 s; closing 20 - 10 = 10 m/s
    # (speeds, not projections): TTC 2.55 s.
    theta = np.deg2rad(angle_deg)
    lead = straight(30.0, 0.0)
    lead[:, 2] = theta
    lead[:, 3:5] = [10.0 * np.cos(theta), 10.0 * np.sin(theta)]
    a, index = tracks_of(straight_road(), straight(0.0, 20.0), lead)
    assert (a.lane[1] == 0).all()  # same lane: only the heading decides
    m = pair(a, index)
    assert m["ok"][0] == follows
    if follows:
        assert (m["thw"][0], m["ttc"][0]) == pytest.approx((1.275, 2.55), abs=1e-4)


def test_only_same_or_directly_connected_lanes() -> None:
    # Lane "a" (x -100..100, y 0) continues into "b" (x 100..300, y 0); "c" runs beside "b" (y 3.6) and is not
    # connected to "a". Follower at x = 90 in "a"; a leader at x = 110 in "b" follows across the lane joint
    # (gap 20 - 4.5 = 15.5 m, THW 15.5 / 20 = 0.775 s); one at x = 110 in "c" does not (another lane).
    lanes = (
        LaneSpec("a", np.array([[-100.0, 0.0], [100.0, 0.0]]), 3.6, successors=("b",)),
        LaneSpec("b", np.array([[100.0, 0.0], [300.0, 0.0]]), 3.6),
        LaneSpec("c", np.array([[100.0, 3.6], [300.0, 3.6]]), 3.6),
    )
    road = RoadDescription("polylines", lanes)
    a, index = tracks_of(road, straight(90.0, 20.0), straight(110.0, 15.0), straight(110.0, 15.0, y=3.6))
    assert [int(a.lane[k, 0]) for k in range(3)] == [0, 1, 2]
    m = pair(a, index, 0, 1)
    assert m["ok"][0] and m["thw"][0] == pytest.approx(0.775, abs=1e-4)
    assert not pair(a, index, 0, 2)["ok"].any()


def test_social_features_reduce_the_per_step_measures() -> None:
    # The scoring features are the maxima over the steps of the per-step inverses: same numbers, bit for bit.
    a, index = tracks_of(
        straight_road(), straight(0.0, 20.0), straight(40.0, 20.0, accel=-4.0), straight(-30.0, 22.0, length=12.0)
    )
    I, J = np.array([0, 1, 0, 2]), np.array([1, 0, 2, 0])
    ctx = TrackContext(a, index)
    feats, active = social_features(ctx, ctx, I, J, index)
    st = following_per_step(a, a, I, J, index)
    assert active.all() and st.rows.tolist() == [0, 1, 2, 3]
    for name, per_step in (("inv_thw", st.inv_thw), ("inv_ttc", st.inv_ttc), ("drac", st.drac)):
        np.testing.assert_array_equal(feats[name], np.where(st.ok, per_step, 0.0).max(1))
    assert feats["drac"][0] == pytest.approx(1.1636, abs=1e-4)  # lead braking at t = 2 s (above)
