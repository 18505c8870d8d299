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

from collections import Counter
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


# ------------------------------------------------------------------------------------------------ (b) crime
US101 = sorted(NGSIM.glob("USA_US101-*.xml"))
FRAMES = ("recorded", "aligned")
WRAP_DEG = 10.0
"""crime's lanelet orientation at the leader differing by more than this from the one at the follower (both on the
follower's lanelet, metres apart on a straight freeway) is its interpolation across the 0 / 2 pi wrap (its own TODO
in ``get_orientation_point``): the projected speed is then garbage; such samples leave the TTC / DRAC rows."""
TTC_HORIZON_S = 20.0
"""TTC rows keep samples with a finite TTC below this in at least one of the two: at equal speeds ours divides by a
closing speed of float noise (1e16 s) and crime's by a projection residue (1e4 s), both meaning "no conflict"."""


RESOLUTION = {"m": 0.01, "s": 0.1, "m/s2": 0.01}
"""crime rounds THW to 0.1 s and TTC / ALongReq to 0.01; relative differences are taken only where the larger of the
two values is at least 10 such steps (below, they measure crime's rounding, not the definitions)."""


def agreement(ours: np.ndarray, crime: np.ndarray, resolution: float) -> dict[str, float]:
    """n, Pearson r, Spearman rho, median / 90th percentile of |ours - crime| and of the relative difference
    |ours - crime| / max(|ours|, |crime|) (where that maximum is >= 10 x ``resolution``)."""
    from scipy.stats import spearmanr  # scipy comes with commonroad-crime; this part runs only where it is installed

    d = np.abs(ours - crime)
    big = np.maximum(np.abs(ours), np.abs(crime))
    rel = (d / np.maximum(big, 1e-12))[big >= 10.0 * resolution]
    return {
        "n": float(ours.size), "pearson": float(np.corrcoef(ours, crime)[0, 1]),
        "spearman": float(spearmanr(ours, crime).statistic), "med_abs": float(np.median(d)),
        "p90_abs": float(np.percentile(d, 90)), "med_rel": float(np.median(rel)) if rel.size else np.nan,
        "p90_rel": float(np.percentile(rel, 90)) if rel.size else np.nan,
    }


def rows_of(o: dict[str, np.ndarray], c: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The compared quantities of one frame: name -> (ours, crime) on the samples where both definitions apply.

    Rows marked "x crime frame terms" multiply ours by the factors items 2 and 3 of `crime_crosscheck` predict
    (crime's bumper shift and its speed projection with cos of the absolute lanelet orientation): if they agree,
    those two items explain the raw difference.
    """
    applies = (c["same"] == 1) & np.isfinite(c["hw"])
    lane_ok = np.abs(np.angle(np.exp(1j * (c["dir_other"] - c["dir_ego"])))) < np.deg2rad(WRAP_DEG)
    closing = o["v_follow"] > o["v_lead"]
    both_ttc = np.isfinite(o["ttc"]) & np.isfinite(c["ttc"]) & (np.minimum(o["ttc"], c["ttc"]) < TTC_HORIZON_S)
    const_vel = np.abs(c["a_other"] - c["a_ego"]) <= 0.1  # crime's TTC branch without accelerations
    drac = applies & lane_ok & closing & np.isfinite(c["a_req"])
    # Item 2: HW = path gap + L_f / 2 (1 - cos - sin)(lanelet at the follower) + L_l / 2 (1 - cos - sin)(at the leader).
    hw_pred = c["path_gap"] + 0.5 * o["length_follow"] * (1.0 - np.cos(c["dir_ego"]) - np.sin(c["dir_ego"]))
    hw_pred += 0.5 * o["length_lead"] * (1.0 - np.cos(c["dir_other"]) - np.sin(c["dir_other"]))
    # Item 3: crime's closing speed: each speed x sqrt(1 + sin^2 heading) x cos(crime's lanelet orientation there).
    v_f = o["v_follow"] * np.sqrt(1.0 + np.sin(c["h_ego"]) ** 2) * np.cos(c["dir_ego"])
    closing_proj = v_f - o["v_lead"] * np.sqrt(1.0 + np.sin(c["h_other"]) ** 2) * np.cos(c["dir_other"])
    closing_ours = o["v_follow"] - o["v_lead"]
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc_framed = o["ttc"] * (c["hw"] / o["gap"]) * (closing_ours / closing_proj)
        drac_framed = o["drac"] * (o["gap"] / c["hw"]) * (closing_proj / closing_ours) ** 2
    o = {**o, "hw_pred": hw_pred, "ttc_framed": ttc_framed, "drac_framed": drac_framed}
    sel = {
        "gap vs path gap (m)": (applies, "gap", "path_gap", 1.0),
        "gap vs HW (m)": (applies, "gap", "hw", 1.0),
        "HW predicted by item 2 vs HW (m)": (applies & lane_ok, "hw_pred", "hw", 1.0),
        "THW (s)": (applies & np.isfinite(o["thw"]) & np.isfinite(c["thw"]), "thw", "thw", 1.0),
        "TTC (s)": (applies & lane_ok & both_ttc, "ttc", "ttc", 1.0),
        "TTC, crime const. velocity (s)": (applies & lane_ok & both_ttc & const_vel, "ttc", "ttc", 1.0),
        "  same, x crime frame terms (s)": (applies & lane_ok & both_ttc & const_vel, "ttc_framed", "ttc", 1.0),
        "DRAC, closing (m/s2)": (drac, "drac", "a_req", -1.0),
        "DRAC, closing, a_lead<=0.05 (m/s2)": (drac & (np.abs(c["a_other"]) <= 0.05), "drac", "a_req", -1.0),
        "  same, x crime frame terms (m/s2)": (drac & (np.abs(c["a_other"]) <= 0.05), "drac_framed", "a_req", -1.0),
    }
    return {name: (o[a][m], sign * c[b][m]) for name, (m, a, b, sign) in sel.items()}


def unit_of(name: str) -> float:
    return RESOLUTION[name[name.rindex("(") + 1 : name.rindex(")")]]


def summarise(per_file: list[dict], files: list[str]) -> dict:
    """Pooled samples of all files, counts and the agreement rows of both frames."""
    run: dict = {k: {n: np.concatenate([e[k][n] for e in per_file]) for n in per_file[0][k]} for k in ("ours", *FRAMES)}
    run["files"] = files
    run["per_file_samples"] = [int(e["ours"]["step"].size) for e in per_file]
    run["crime_only"] = tuple(int(sum(e["crime_only"][k] for e in per_file)) for k in (0, 1))
    run["failures"] = {f: dict(sum((Counter(e["failures"][f]) for e in per_file), Counter())) for f in FRAMES}
    run["rows"] = {}
    for f in FRAMES:
        run["rows"][f] = {name: agreement(*pair, unit_of(name)) for name, pair in rows_of(run["ours"], run[f]).items()}
    return run


@pytest.fixture(scope="module")
def crime_run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Our samples and crime's values on the three US-101 recordings, in both frames (2-4 min)."""
    pytest.importorskip("commonroad_crime", reason="commonroad-crime not installed (crosscheck extra, see README)")
    if not US101:
        pytest.skip(f"NGSIM US-101 CommonRoad files not found at {NGSIM} (shared data folder absent)")
    import crime_crosscheck as cc

    aligned_dir = tmp_path_factory.mktemp("aligned")
    per_file: list[dict] = []
    for path in US101:
        o = cc.ours(path)
        entry: dict = {"ours": o, "failures": {}}
        for frame in FRAMES:
            sce = cc.load(path, None if frame == "recorded" else aligned_dir)
            entry[frame], entry["failures"][frame] = cc.crime_measures(sce, o)
            if frame == "recorded":
                entry["crime_only"] = cc.crime_only(path, sce, o)
        per_file.append(entry)
    run = summarise(per_file, [p.name for p in US101])
    print_table(run)
    return run


def print_table(run: dict) -> None:
    o = run["ours"]
    print(f"\ncommonroad-crime cross-check on {', '.join(run['files'])}: {o['step'].size} (follower, leader, step) "
          f"samples of seal ({run['per_file_samples']} per file)")
    print(f"crime-only following samples (same lanelet, ahead on the path, seal: not following): {run['crime_only'][0]}"
          f", of which in lanes seal counts as different / unconnected: {run['crime_only'][1]}")
    for frame in FRAMES:
        c = run[frame]
        applies = int(((c["same"] == 1) & np.isfinite(c["hw"])).sum())
        print(f"\n[{frame} frame] crime applies (same lanelet, HW finite): {applies}"
              f"; crime errors: {run['failures'][frame]}; crime THW finite: {int(np.isfinite(c['thw']).sum())}"
              f", TTC finite: {int(np.isfinite(c['ttc']).sum())} (ours: {int(np.isfinite(o['ttc']).sum())})")
        short = (c["same"] == 1) & np.isfinite(c["hw"]) & (o["ttc"] < TTC_HORIZON_S)
        print(f"our TTC < {TTC_HORIZON_S:.0f} s: {int(short.sum())}, crime's TTC infinite there (item 4): "
              f"{int((short & np.isinf(c['ttc'])).sum())}")
        print(f"{'quantity':38s} {'n':>5s} {'pearson':>8s} {'spearman':>8s} {'med|d|':>8s} {'p90|d|':>8s} "
              f"{'med rel':>8s} {'p90 rel':>8s}")
        for name, s in run["rows"][frame].items():
            print(f"{name:38s} {int(s['n']):5d} {s['pearson']:8.3f} {s['spearman']:8.3f} {s['med_abs']:8.3f} "
                  f"{s['p90_abs']:8.3f} {s['med_rel']:8.3f} {s['p90_rel']:8.3f}")



def row(run: dict, frame: str, name: str) -> dict[str, float]:
    return run["rows"][frame][name]


def test_crime_sees_the_same_following_pairs(crime_run: dict) -> None:
    # At every sample of ours crime's same-lanelet test holds and the leader is ahead on crime's reference path.
    c = crime_run["recorded"]
    assert crime_run["ours"]["step"].size > 4000
    assert ((c["same"] == 1) & np.isfinite(c["hw"])).mean() >= 0.99
    # crime counts more samples as following (item 6: a body touching the lanelet is enough); every one of them is
    # a vehicle seal puts in another, unconnected lane (neighbours near the line, lane changes).
    only, other_lane = crime_run["crime_only"]
    assert other_lane == only


def test_crime_bumper_gap_and_headway_distance(crime_run: dict) -> None:
    # Our centre distance minus half lengths against the distance along crime's reference path: cm apart (the
    # path is a smoothed centre line; a lateral offset adds offset^2 / (2 gap) to the centre distance).
    for frame in FRAMES:
        s = row(crime_run, frame, "gap vs path gap (m)")
        assert s["pearson"] > 0.9999 and s["med_abs"] < 0.02 and s["p90_abs"] < 0.1
        # crime's HW is that path gap with its diagonal bumper shift (item 2), to a few cm.
        s = row(crime_run, frame, "HW predicted by item 2 vs HW (m)")
        assert s["med_abs"] < 0.05 and s["p90_abs"] < 0.15
    # Recorded frame (road at -41 deg): HW exceeds our gap by ~0.9 x the half lengths; road along +x: none.
    assert 4.0 < row(crime_run, "recorded", "gap vs HW (m)")["med_abs"] < 5.5
    s = row(crime_run, "aligned", "gap vs HW (m)")
    assert s["med_abs"] < 0.1 and s["p90_abs"] < 0.2


def test_crime_time_headway(crime_run: dict) -> None:
    # crime's THW is the realised time until the follower's front reaches the leader's rear position (item 1),
    # ours the instantaneous gap / speed: equal at constant speed, apart by the speed changes within the headway
    # plus crime's rounding up to whole 0.1 s steps. Frame independent.
    for frame in FRAMES:
        s = row(crime_run, frame, "THW (s)")
        assert s["n"] > 2000 and s["spearman"] > 0.95 and s["med_abs"] < 0.15 and s["p90_rel"] < 0.25


def test_crime_time_to_collision(crime_run: dict) -> None:
    # Where crime uses constant velocity (item 4) on the road-aligned frame: ours to crime's 2-decimal rounding.
    s = row(crime_run, "aligned", "TTC, crime const. velocity (s)")
    assert s["n"] >= 150 and s["pearson"] > 0.99 and s["med_rel"] < 0.01 and s["p90_rel"] < 0.03
    # Recorded frame: 25 % apart, all of it crime's frame terms (items 2 and 3).
    assert row(crime_run, "recorded", "TTC, crime const. velocity (s)")["med_rel"] > 0.15
    s = row(crime_run, "recorded", "  same, x crime frame terms (s)")
    assert s["med_rel"] < 0.01 and s["p90_rel"] < 0.03


def test_crime_deceleration_rate(crime_run: dict) -> None:
    # Closing samples where crime's leader-acceleration term (item 5) is negligible: ours vs -ALongReq.
    s = row(crime_run, "aligned", "DRAC, closing, a_lead<=0.05 (m/s2)")
    assert s["n"] >= 500 and s["pearson"] > 0.98 and s["med_abs"] < 0.01 and s["p90_abs"] < 0.05
    s = row(crime_run, "recorded", "  same, x crime frame terms (m/s2)")
    assert s["pearson"] > 0.95 and s["med_abs"] < 0.01 and s["p90_abs"] < 0.05
