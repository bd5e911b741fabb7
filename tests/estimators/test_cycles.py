"""Cycle segmentation (estimators.cycles) on realistic synthetic wrist paths.

Paths: a rounded rectangle 0.30 × 0.20 m traced in ~5 s cycles (±15 %), with a speed profile,
1 cm damped oscillations after each corner (slack ropes) and 3 mm noise, at 25 Hz; a
back-and-forth reaching motion (minimum-jerk strokes, dwells, sway); rests. The truth is the
generator's continuous cycle phase ``u(t)`` (cycle index + fraction).
"""

from __future__ import annotations

import json
import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.cycles import (
    Boundary,
    CycleParams,
    CycleSegmenter,
    PathAndReach,
    _MovingWindow,
    path_and_reach,
)

FS = 25.0


# ----------------------------------------------------------------------------- generators


def rounded_rect(s: np.ndarray, a: float = 0.15, b: float = 0.10, rc: float = 0.04):
    """Point at perimeter fraction ``s`` (CCW from the middle of the right side) of a
    2a × 2b rectangle with corner radius rc; also the perimeter fractions of the corners."""
    seg = [b - rc, math.pi / 2 * rc, 2 * (a - rc), math.pi / 2 * rc, 2 * (b - rc)]
    seg += [math.pi / 2 * rc, 2 * (a - rc), math.pi / 2 * rc, b - rc]
    total = sum(seg)
    cum = np.concatenate(([0.0], np.cumsum(seg)))
    d = (np.asarray(s) % 1.0) * total
    k = np.clip(np.searchsorted(cum, d, side="right") - 1, 0, 8)
    w = d - cum[k]
    out = np.empty((d.size, 2))
    ax, by = a - rc, b - rc
    corners = [(ax, by), (-ax, by), (-ax, -by), (ax, -by)]
    lines = {
        0: lambda w: np.c_[np.full(w.size, a), w],
        2: lambda w: np.c_[ax - w, np.full(w.size, b)],
        4: lambda w: np.c_[np.full(w.size, -a), by - w],
        6: lambda w: np.c_[-ax + w, np.full(w.size, -b)],
        8: lambda w: np.c_[np.full(w.size, a), -by + w],
    }
    for i in range(9):
        m = k == i
        if i in lines:
            out[m] = lines[i](w[m])
        else:
            ci = (i - 1) // 2
            ang = ci * math.pi / 2 + w[m] / rc
            out[m] = np.c_[corners[ci][0] + rc * np.cos(ang), corners[ci][1] + rc * np.sin(ang)]
    corner_fractions = [(cum[2 * i + 1] + seg[2 * i + 1] / 2) / total for i in range(4)]
    return out, corner_fractions


def loop_session(
    seed=0,
    n_cycles=20,
    period=5.0,
    direction=1,
    rest_before=2.0,
    rest_after=2.0,
    rests=(),
    noise=0.003,
    osc=0.01,
    centre=(0.10, 0.45),
):
    """Wrist tracing the rounded rectangle. ``rests``: ((after cycle k, duration s), ...).
    Returns t (n,), wrist (n,3), true phase u (n,) and the rest intervals."""
    rng = np.random.default_rng(seed)
    durations = period * rng.uniform(0.85, 1.15, n_cycles)
    rest_after_cycle = dict(rests)
    segments, rest_intervals, t = [], [(0.0, rest_before)], rest_before
    for k in range(n_cycles):
        segments.append((t, t + durations[k], k))
        t += durations[k]
        if k in rest_after_cycle:
            rest_intervals.append((t, t + rest_after_cycle[k]))
            t += rest_after_cycle[k]
    rest_intervals.append((t, t + rest_after))
    t_end = t + rest_after
    tt = np.arange(0.0, t_end, 1.0 / FS)
    u = np.zeros_like(tt)
    for t0, t1, k in segments:
        m = tt >= t0
        tau = np.clip((tt[m] - t0) / (t1 - t0), 0.0, 1.0)
        # slower around the four corners, faster along the sides
        u[m] = k + tau + 0.35 / (8 * math.pi) * np.sin(8 * math.pi * tau)
    s = u if direction > 0 else -u
    xy, corner_f = rounded_rect(s)
    outward = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) / math.sqrt(2)
    for k in range(n_cycles):
        for ci, f in enumerate(corner_f):
            i = int(np.searchsorted(u, k + (f if direction > 0 else 1.0 - f)))
            if i >= tt.size:
                continue
            dt = tt[i:] - tt[i]
            xy[i:] += (osc * np.exp(-dt / 0.3) * np.sin(2 * math.pi * 3 * dt))[:, None] * outward[
                ci
            ]
    wrist = np.c_[xy + centre, np.full(tt.size, 0.9)] + rng.normal(0, noise, (tt.size, 3))
    return tt, wrist, u, rest_intervals


def minjerk(tau):
    tau = np.clip(tau, 0.0, 1.0)
    return 10 * tau**3 - 15 * tau**4 + 6 * tau**5


def reach_session(seed=0, n_cycles=20, angle_deg=10.0, rests=(), noise=0.003, osc=0.01):
    """Forward reaching (angle from +y), 0.25 m strokes: out (~1.2 s), dwell at the far end,
    back, dwell at the near end; ±15 % timing. Returns t, wrist, the true return times (the
    return stroke passing 25 % of the range from the near end) and the rest intervals."""
    rng = np.random.default_rng(seed)
    axis = np.array([math.sin(math.radians(angle_deg)), math.cos(math.radians(angle_deg))])
    normal = np.array([-axis[1], axis[0]])
    rest_after_cycle = dict(rests)
    strokes, returns, rest_intervals, t = [], [], [(0.0, 2.0)], 2.0
    tau = np.linspace(0, 1, 200001)
    t_quarter = tau[np.searchsorted(minjerk(tau), 0.75)]  # back stroke at 25 % from near end
    for k in range(n_cycles):
        f = rng.uniform(0.85, 1.15)
        out_s, far_s = 1.2 * f, 0.3 * f
        back_s, near_s = 1.2 * f * rng.uniform(0.9, 1.1), 0.8 * f * rng.uniform(0.7, 1.3)
        strokes.append((t, t + out_s, 0.0, 1.0))
        t += out_s + far_s
        strokes.append((t, t + back_s, 1.0, 0.0))
        returns.append(t + back_s * t_quarter)
        t += back_s + near_s
        if k in rest_after_cycle:
            rest_intervals.append((t, t + rest_after_cycle[k]))
            t += rest_after_cycle[k]
    rest_intervals.append((t, t + 2.0))
    tt = np.arange(0.0, t + 2.0, 1.0 / FS)
    s = np.zeros_like(tt)
    sway = np.zeros_like(tt)
    ring = np.zeros((tt.size, 2))
    for t0, t1, a, b in strokes:
        m = tt >= t0
        s[m] = a + (b - a) * minjerk((tt[m] - t0) / (t1 - t0))
        mm = m & (tt < t1)
        sway[mm] += 0.01 * np.sin(math.pi * (tt[mm] - t0) / (t1 - t0)) * (b - a)
        dt = tt[tt >= t1] - t1
        ring[tt >= t1] += (
            (osc * np.exp(-dt / 0.3) * np.sin(6 * math.pi * dt))[:, None] * axis * (b - a)
        )
    xy = np.array([0.05, 0.30]) + np.outer(0.25 * s, axis) + np.outer(sway, normal) + ring
    wrist = np.c_[xy, np.full(tt.size, 0.85)] + rng.normal(0, noise, (tt.size, 3))
    return tt, wrist, np.array(returns), rest_intervals


# ----------------------------------------------------------------------------- helpers


def run(seg: CycleSegmenter, t, wrist, sizes=None):
    """Feed in chunks of the given sizes (the rest at once); all boundaries."""
    out, i = [], 0
    for s in sizes or []:
        if i >= t.size:
            break
        out += seg.update(t[i : i + s], wrist[i : i + s])
        i += s
    if i < t.size:
        out += seg.update(t[i:], wrist[i:])
    return out


def key(bs):
    return [(float(b), b.cycle_start, b.source, b.detected_at) for b in bs]


def true_time(t, u, level):
    """Time at which the (nondecreasing) true phase reaches ``level``."""
    i = int(np.searchsorted(u, level))
    return t[i - 1] + (level - u[i - 1]) / (u[i] - u[i - 1]) * (t[i] - t[i - 1])


def phase_check(t, u, bs):
    """Common boundary phase (circular mean), true cycle index of each boundary and the time
    error of each boundary against the true crossing of that phase."""
    b = np.array([float(x) for x in bs])
    ub = np.interp(b, t, u)
    ph = (np.angle(np.mean(np.exp(2j * np.pi * ub))) / (2 * np.pi)) % 1.0
    k = np.round(ub - ph).astype(int)
    err = np.array([bb - true_time(t, u, kk + ph) for bb, kk in zip(b, k, strict=True)])
    return ph, k, err


def in_rest(b, rests, margin=0.2):
    return any(r0 + margin < b < r1 for r0, r1 in rests)


# ----------------------------------------------------------------------------- path


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("seed", [0, 1])
def test_path_finds_every_cycle_at_a_consistent_phase(seed, direction):
    t, wrist, u, _ = loop_session(seed=seed, direction=direction)
    bs = CycleSegmenter(CycleParams(mode="path")).update(t, wrist)
    ph, k, err = phase_check(t, u, bs)
    # one warm-up turn after the start, then every true crossing of that phase, once
    assert k.tolist() == list(range(1, 20))
    assert np.max(np.abs(err)) < 0.3
    assert all(b.source == "path" for b in bs)
    # reported at the first sample at/after the crossing
    assert [b.detected_at for b in bs] == [t[t >= b][0] for b in bs]
    assert bs[0].cycle_start is None
    assert [b.cycle_start for b in bs[1:]] == [float(b) for b in bs[:-1]]
    # cycle durations against the true durations at that phase
    true_d = np.diff([true_time(t, u, kk + ph) for kk in k])
    np.testing.assert_allclose(np.diff(np.array(bs, dtype=float)), true_d, atol=0.3)
    # the durations vary as generated (±15 %), so this is not a fixed period
    assert np.ptp(true_d) > 0.5


def test_path_rests_give_no_boundaries_and_restart():
    rests = ((6, 15.0), (12, 3.0))  # a long rest (> centre window) and a short pause
    t, wrist, u, rest_iv = loop_session(seed=3, n_cycles=20, rests=rests)
    bs = CycleSegmenter(CycleParams(mode="path")).update(t, wrist)
    assert not [b for b in bs if in_rest(float(b), rest_iv)]
    _, k, err = phase_check(t, u, bs)
    assert np.max(np.abs(err)) < 0.3
    assert len(set(k.tolist())) == len(k)  # no double boundaries
    # the long rest restarts the detector: one warm-up turn is lost, the boundary after it
    # only opens a cycle; the short pause does not
    assert k.tolist() == [*range(1, 7), *range(8, 20)]
    opens = [i for i, b in enumerate(bs) if b.cycle_start is None]
    assert opens == [0, 6]
    # the cycle containing the short pause is one cycle, about 3 s longer
    pause = next(i for i, b in enumerate(bs) if float(b) > rest_iv[2][1]) - 1
    assert 3.0 + 0.85 * 5 - 0.3 < float(bs[pause + 1]) - float(bs[pause]) < 3.0 + 1.15 * 5 + 0.3


def test_path_ignores_reaching_and_too_fast_or_too_slow_turns():
    t, wrist, _, _ = reach_session(seed=1)
    assert CycleSegmenter(CycleParams(mode="path")).update(t, wrist) == []
    # a 0.6 s circle (faster than min_cycle_s) and a 40 s circle (slower than max_cycle_s)
    for period in (0.6, 40.0):
        tt = np.arange(0.0, 100.0, 1 / FS)
        ang = 2 * math.pi * tt / period
        w = np.c_[0.1 * np.cos(ang), 0.4 + 0.1 * np.sin(ang), np.zeros_like(tt)]
        w += np.random.default_rng(0).normal(0, 0.003, w.shape)
        bs = CycleSegmenter(CycleParams(mode="path")).update(tt, w)
        assert all(b.cycle_start is None for b in bs), period
    # ... while a 20 s circle is fine
    tt = np.arange(0.0, 100.0, 1 / FS)
    ang = 2 * math.pi * tt / 20.0
    w = np.c_[0.1 * np.cos(ang), 0.4 + 0.1 * np.sin(ang), np.zeros_like(tt)]
    bs = CycleSegmenter(CycleParams(mode="path")).update(tt, w)
    np.testing.assert_allclose(np.diff(np.array(bs, dtype=float)), 20.0, atol=0.05)


# ----------------------------------------------------------------------------- reach


@pytest.mark.parametrize("angle", [10.0, 80.0])
def test_reach_finds_every_return(angle):
    t, wrist, returns, rest_iv = reach_session(seed=2, angle_deg=angle, rests=((9, 15.0),))
    bs = CycleSegmenter(CycleParams(mode="reach")).update(t, wrist)
    b = np.array(bs, dtype=float)
    nearest = np.abs(b[:, None] - returns[None, :]).argmin(axis=1)
    assert nearest.tolist() == list(range(len(returns)))  # every return, once, in order
    assert np.max(np.abs(b - returns[nearest])) < 0.3
    assert not [x for x in b if in_rest(x, rest_iv)]
    assert all(x.source == "reach" for x in bs)
    assert [x.detected_at for x in bs] == [t[t >= x][0] for x in bs]
    # the 15 s rest restarts the detector: the boundary after it opens a new sequence
    assert [i for i, x in enumerate(bs) if x.cycle_start is None] == [0, 10]


# ----------------------------------------------------------------------------- events


def test_auto_switches_from_path_to_events():
    t, wrist, _, _ = loop_session(seed=4, n_cycles=12)
    seg = CycleSegmenter()  # auto
    first = run(seg, t[t < 30.0], wrist[t < 30.0], [7] * 200)
    assert first and all(b.source == "path" for b in first)
    events = [31.0, 36.5, 36.9, 41.7, 48.2]  # 36.9: closer than min_cycle_s, ignored
    assert seg.active_source == "path"
    for e in events:
        seg.add_event(e)
    assert seg.active_source == "path"  # until the data reaches the first event
    rest = run(seg, t[t >= 30.0], wrist[t >= 30.0], [5] * 1000)
    assert seg.active_source == "event"
    path_after = [b for b in rest if b.source == "path"]
    assert all(float(b) < 31.0 for b in path_after)  # path only for samples before the event
    ev = [b for b in rest if b.source == "event"]
    assert [float(b) for b in ev] == [31.0, 36.5, 41.7, 48.2]
    assert [b.cycle_start for b in ev] == [None, 31.0, 36.5, 41.7]
    assert [b.detected_at for b in ev] == [31.0, 36.5, 41.7, 48.2]


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.integers(1, 40), min_size=1, max_size=80),
    st.lists(st.floats(3.0, 58.0), min_size=1, max_size=12, unique=True),
    st.randoms(use_true_random=False),
)
def test_events_depend_on_timestamps_not_arrival(sizes, event_times, rnd):
    """Events arrive at random points of the sample stream, but never after data past their
    own time: the boundaries are the same as with all events known up front."""
    t = np.arange(0.0, 60.0, 1 / FS)
    wrist = np.zeros((t.size, 3))
    ref = CycleSegmenter(CycleParams(mode="events"))
    for e in event_times:
        ref.add_event(e)
    expected = key(ref.update(t, wrist))
    # expected: events at least min_cycle_s apart (greedy), cycles closing when <= max
    kept: list[float] = []
    for e in sorted(event_times):
        if not kept or e - kept[-1] >= 1.0:
            kept.append(e)
    assert [x[0] for x in expected] == kept
    seg = CycleSegmenter(CycleParams(mode="events"))
    pending = sorted(event_times, key=lambda _: rnd.random())
    got, i = [], 0
    for s in [*sizes, t.size]:
        if i >= t.size:
            break
        # deliver some events, all that are due before this chunk's data reaches them
        hi_t = t[min(i + s, t.size) - 1]
        due = [e for e in pending if e <= hi_t]
        extra = [e for e in pending if e > hi_t and rnd.random() < 0.3]
        for e in due + extra:
            seg.add_event(e)
            pending.remove(e)
        got += seg.update(t[i : i + s], wrist[i : i + s])
        i += s
    assert key(got) == expected


def test_late_event_keeps_its_time():
    t = np.arange(0.0, 20.0, 1 / FS)
    wrist = np.zeros((t.size, 3))
    seg = CycleSegmenter(CycleParams(mode="events"))
    seg.add_event(2.0)
    assert [float(b) for b in seg.update(t[:100], wrist[:100])] == [2.0]  # data up to 3.96 s
    seg.add_event(3.5)  # arrives after data past 3.5 s
    late = seg.update(t[100:101], wrist[100:101])
    assert key(late) == [(3.5, 2.0, "event", math.nextafter(t[99], math.inf))]
    assert seg.update(t[:0], wrist[:0]) == []
    seg.add_event(3.0)  # before the last boundary: cannot be honoured
    assert seg.update(t[101:], wrist[101:]) == []


# ----------------------------------------------------------------------------- streaming


_LOOP = loop_session(seed=5, n_cycles=8, rests=((3, 12.0),))
_REACH = reach_session(seed=6, n_cycles=10, rests=((4, 12.0),))
_FULL = {
    "path": key(CycleSegmenter(CycleParams(mode="path")).update(_LOOP[0], _LOOP[1])),
    "reach": key(CycleSegmenter(CycleParams(mode="reach")).update(_REACH[0], _REACH[1])),
}


@pytest.mark.parametrize("mode", ["path", "reach"])
def test_one_sample_at_a_time_is_bit_identical(mode):
    t, wrist = (_LOOP if mode == "path" else _REACH)[:2]
    got = run(CycleSegmenter(CycleParams(mode=mode)), t, wrist, [1] * t.size)
    assert len(_FULL[mode]) >= 6
    assert key(got) == _FULL[mode]


# chunks of up to 12 samples take the per-sample path, larger ones the vectorised path
_SIZES = st.one_of(
    st.lists(st.integers(1, 40), min_size=40, max_size=150),
    st.lists(st.integers(1, 400), max_size=10),
)


@settings(max_examples=30, deadline=None)
@given(st.sampled_from(["path", "reach"]), _SIZES)
def test_any_chunking_is_bit_identical(mode, sizes):
    t, wrist = (_LOOP if mode == "path" else _REACH)[:2]
    assert key(run(CycleSegmenter(CycleParams(mode=mode)), t, wrist, sizes)) == _FULL[mode]


# live fast paths: `push` (one sample, no numpy) and the moving window's per-sample form
# (deques, moved to and from the arrays when a caller switches paths) against `update`


@settings(max_examples=30, deadline=None)
@given(
    st.sampled_from(["path", "reach", "auto"]),
    st.lists(st.tuples(st.booleans(), st.integers(1, 40)), min_size=1, max_size=60),
)
def test_push_and_update_in_any_mix_are_bit_identical(mode, plan):
    t, wrist = (_REACH if mode == "reach" else _LOOP)[:2]
    events = [t[len(t) // 2] + 0.013, t[len(t) // 2] + 6.0]  # auto: path, then events

    def make():
        seg = CycleSegmenter(CycleParams(mode=mode))
        for e in events:
            seg.add_event(e)
        return seg

    ref, seg = make(), make()
    expected = [b for i in range(t.size) for b in ref.update(t[i : i + 1], wrist[i : i + 1])]
    got, i = [], 0
    for pushed, s in [*plan, (True, t.size)]:
        if pushed:
            for j in range(i, min(i + s, t.size)):
                got += seg.push(float(t[j]), float(wrist[j, 0]), float(wrist[j, 1]))
        else:
            got += seg.update(t[i : i + s], wrist[i : i + s])
        i += s
    assert key(got) == key(expected)
    if mode == "auto":
        assert {b.source for b in expected} == {"path", "event"}
    else:
        assert key(got) == _FULL[mode]


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.sampled_from([0.04, 0.04, 0.04, 0.01, 0.13, 0.45, 2.5]), min_size=1, max_size=300),
    st.sampled_from([2, 5]),
    st.integers(0, 2**32 - 1),
)
def test_moving_window_means_by_definition(dts, width, seed):
    """Means and counts of the moving samples in the window, against the definition written
    out sample by sample (irregular times, gaps longer than the window, NaN where nothing
    moved)."""
    p = CycleParams(centre_window_s=2.0, still_window_s=0.3)
    t = 5.0 + np.cumsum(dts)
    rng = np.random.default_rng(seed)
    xy = np.cumsum(rng.normal(0.0, 0.02, (t.size, 2)) * rng.integers(0, 2, (t.size, 1)), axis=0)
    x, y = xy[:, 0], xy[:, 1]
    vals = xy if width == 2 else np.c_[x, y, x * x, y * y, x * y]
    moving = np.zeros(t.size, bool)
    for i in range(t.size):
        j = np.flatnonzero(t <= t[i] - p.still_window_s)
        if len(j):
            moving[i] = np.sum((xy[i] - xy[j[-1]]) ** 2) > p.still_radius_m**2
    win = _MovingWindow(p)
    for i in range(t.size):
        got = np.array(win.step(float(t[i]), float(x[i]), float(y[i]))[:width])
        k = (t >= t[i] - p.centre_window_s) & (np.arange(t.size) <= i) & moving
        want = vals[k].mean(axis=0) if k.any() else np.full(width, np.nan)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_boundary_is_a_float_with_extras():
    b = Boundary(12.5, 7.25, "event")
    assert b == 12.5 and b.closes_cycle and b.source == "event"
    assert json.dumps([b]) == "[12.5]"
    c = pickle.loads(pickle.dumps(b))
    assert (float(c), c.cycle_start, c.source, c.detected_at) == (12.5, 7.25, "event", 12.5)
    assert not Boundary(3.0).closes_cycle


@pytest.mark.parametrize(
    "kw",
    [
        {"mode": "circle"},
        {"min_cycle_s": 5.0, "max_cycle_s": 4.0},
        {"centre_window_s": 0.0},
        {"reach_return_fraction": 0.7, "reach_arm_fraction": 0.6},
        {"max_phase_step_rad": 4.0},
    ],
)
def test_invalid_params_are_rejected(kw):
    with pytest.raises(ValueError):
        CycleParams(**kw)


@pytest.mark.parametrize("session", ["loop", "reach"])
def test_path_and_reach_in_one_pass_equals_each_detector_alone(session):
    t, wrist = (_LOOP if session == "loop" else _REACH)[:2]
    path, reach = path_and_reach(t, wrist)
    alone = [CycleSegmenter(CycleParams(mode=m)).update(t, wrist) for m in ("path", "reach")]
    assert len(alone[0] if session == "loop" else alone[1]) >= 6
    assert key(path) == key(alone[0])
    assert key(reach) == key(alone[1])
    assert path_and_reach(t[:0], wrist[:0]) == ([], [])


@pytest.mark.parametrize("session", ["loop", "reach"])
def test_path_and_reach_streaming_in_any_chunks_equals_one_pass(session):
    t, wrist = (_LOOP if session == "loop" else _REACH)[:2]
    path, reach = path_and_reach(t, wrist)
    assert len(path if session == "loop" else reach) >= 6
    rng = np.random.default_rng(3)
    for cuts in ([1], sorted(rng.choice(np.arange(1, len(t)), 40, replace=False))):
        both = PathAndReach()
        for tc, wc in zip(np.split(t, cuts), np.split(wrist, cuts), strict=True):
            both.update(tc, wc)
        assert key(both.path) == key(path)
        assert key(both.reach) == key(reach)
