"""Compensation rule (paper §3.4): displacement, indicator state, episodes and cycle verdicts
(estimators.compensation, estimators.verdicts), and the whole chain on a synthetic session."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from estimators.compensation import (
    OK,
    OUTSIDE,
    STATE_NAMES,
    UNKNOWN,
    WARNING,
    CompensationParams,
    EpisodeTracker,
    Indicator,
    displacement,
    state_name,
)
from estimators.cycles import Boundary, CycleParams, CycleSegmenter
from estimators.verdicts import CycleJudge
from tests.estimators.test_cycles import loop_session

FS = 25.0

# ----------------------------------------------------------------------------- displacement


def test_displacement_norms_and_nan():
    rng = np.random.default_rng(0)
    s = rng.normal(0, 0.1, (50, 3))
    nom = np.array([0.1, -0.2, 0.5])
    s[7, 2] = np.nan  # z only: unknown in 3d, irrelevant horizontally
    s[9, 0] = np.nan
    h = displacement(s, nom)
    d3 = displacement(s, nom, "3d")
    ref_h = np.linalg.norm((s - nom)[:, :2], axis=1)
    ref_3 = np.linalg.norm(s - nom, axis=1)
    np.testing.assert_allclose(h, ref_h, rtol=1e-12)
    np.testing.assert_allclose(d3, ref_3, rtol=1e-12)
    assert np.isfinite(h[7]) and np.isnan(d3[7]) and np.isnan(h[9]) and np.isnan(d3[9])
    # per-sample nominal (N,3), with NaN rows where no nominal exists yet
    noms = np.tile(nom, (50, 1))
    noms[:5] = np.nan
    hn = displacement(s, noms)
    assert np.isnan(hn[:5]).all()
    np.testing.assert_array_equal(hn[5:], h[5:])
    with pytest.raises(ValueError):
        displacement(s, nom, "vertical")  # type: ignore[arg-type]


def test_displacement_is_chunk_invariant():
    rng = np.random.default_rng(1)
    s = rng.normal(0, 0.2, (1000, 3))
    whole = displacement(s, np.zeros(3), "3d")
    parts = np.concatenate(
        [displacement(s[i : i + 7], np.zeros(3), "3d") for i in range(0, 1000, 7)]
    )
    np.testing.assert_array_equal(whole, parts)


# ----------------------------------------------------------------------------- indicator


def reference_codes(t, d, tol_m, tolerated, hold):
    """Straightforward per-sample statement of the rule (tolerated: callable of t)."""
    codes, run, t_prev = [], None, -math.inf
    for ti, di in zip(t, d, strict=True):
        if math.isnan(di):
            run = None
            codes.append(UNKNOWN)
        elif di > tol_m:
            if run is None or ti - t_prev > hold:
                run = ti
            codes.append(WARNING if ti - run > tolerated(ti) else OUTSIDE)
        else:
            run = None
            codes.append(OK)
        t_prev = ti
    return np.array(codes)


def feed(ind, t, d, sizes, **kw):
    codes, changes, i = [], [], 0
    for s in [*sizes, t.size]:
        if i >= t.size:
            break
        c, ch = ind.update(t[i : i + s], d[i : i + s], **kw)
        codes.append(c)
        changes += ch
        i += s
    return np.concatenate(codes), changes


def _profile():
    t = np.arange(0.0, 20.0, 1 / FS)
    d = np.full(t.size, 0.05)
    d[(t >= 4.0) & (t < 6.5)] = 0.15  # 2.5 s outside: warning after 1 s
    d[(t >= 10.0) & (t < 11.0)] = np.nan  # no estimate
    d[(t >= 12.0) & (t < 12.6)] = 0.15  # 0.6 s outside: no warning
    return t, d


def test_indicator_states_and_changes():
    t, d = _profile()
    codes, changes = Indicator().update(t, d)
    assert codes.dtype == np.int8
    np.testing.assert_array_equal(codes, reference_codes(t, d, 0.10, lambda _: 1.0, 0.25))
    warn = t[codes == WARNING]
    assert 5.0 < warn[0] <= 5.0 + 1 / FS + 1e-9 and warn[-1] < 6.5
    assert (codes[(t >= 10.0) & (t < 11.0)] == UNKNOWN).all()
    assert not (codes[t > 7.0] == WARNING).any()
    # events: first known state, then changes among known states; the NaN gap between two
    # "ok" samples emits nothing
    assert [s for _, s in changes] == ["ok", "outside", "warning", "ok", "outside", "ok"]
    assert [tc for tc, _ in changes][:2] == [t[0], t[t >= 4.0][0]]
    assert changes[3][0] == t[t >= 6.5][0]


def test_unknown_between_different_states_emits_the_new_state():
    t = np.arange(0.0, 4.0, 1 / FS)
    d = np.where(t < 1.0, 0.05, np.where(t < 2.0, np.nan, 0.2))
    codes, changes = Indicator().update(t, d)
    assert changes == [(t[0], "ok"), (t[t >= 2.0][0], "outside"), (t[t >= 3.04][0], "warning")]
    # a run does not continue across unknown samples
    assert codes[t >= 2.0][0] == OUTSIDE


def test_tolerated_duration_sources():
    t = np.arange(0.0, 12.0, 1 / FS)
    d = np.full(t.size, 0.05)
    d[(t >= 0.5) & (t < 1.3)] = 0.15  # 0.8 s: below the default 1 s
    d[(t >= 4.0) & (t < 4.8)] = 0.15  # 0.8 s: beyond 20 % of a 2.5 s cycle
    d[(t >= 8.0) & (t < 9.5)] = 0.15
    ind = Indicator()
    ind.cycle_completed(0.0, 2.5)  # effective from t >= 2.5
    codes, _ = ind.update(t, d)
    ref = reference_codes(t, d, 0.10, lambda ti: 1.0 if ti < 2.5 else 0.5, 0.25)
    np.testing.assert_array_equal(codes, ref)
    assert not (codes[t < 2.0] == WARNING).any() and (codes[(t > 4.5) & (t < 4.8)] == WARNING).all()
    # the same via Boundary objects passed to update
    ind2 = Indicator()
    c1, _ = ind2.update(t[:60], d[:60])
    c2, _ = ind2.update(t[60:], d[60:], boundaries=[Boundary(2.5, 0.0)])
    np.testing.assert_array_equal(np.concatenate([c1, c2]), ref)
    # fixed warning_after_s ignores cycles; a per-call override beats both
    fixed = Indicator(CompensationParams(warning_after_s=1.2))
    fixed.cycle_completed(0.0, 2.5)
    np.testing.assert_array_equal(
        fixed.update(t, d)[0], reference_codes(t, d, 0.10, lambda _: 1.2, 0.25)
    )
    np.testing.assert_array_equal(
        Indicator().update(t, d, tolerated_s=0.3)[0],
        reference_codes(t, d, 0.10, lambda _: 0.3, 0.25),
    )


def test_data_gap_breaks_an_outside_run():
    t = np.concatenate([np.arange(0.0, 0.8, 0.04), np.arange(1.5, 2.5, 0.04)])
    d = np.full(t.size, 0.2)
    codes, _ = Indicator().update(t, d)
    # without the gap rule the samples after 1.5 s would be "warning" at once
    assert (codes[t < 2.5] != WARNING).all()
    assert (codes == OUTSIDE).all()
    codes, _ = Indicator(CompensationParams(max_hold_s=1.0)).update(t, d)
    assert codes[t >= 1.5][0] == WARNING


_VALUES = st.sampled_from([0.05, 0.099, 0.1, 0.101, 0.3, math.nan])


@st.composite
def displacement_streams(draw):
    runs = draw(st.lists(st.tuples(_VALUES, st.integers(1, 60)), min_size=1, max_size=25))
    d = np.concatenate([np.full(n, v) for v, n in runs])
    dt = np.full(d.size, 1 / FS)
    gaps = draw(st.lists(st.integers(0, d.size - 1), max_size=3))
    dt[gaps] = 0.6  # data gaps longer than max_hold_s
    t = 100.0 + np.cumsum(dt)
    cycles = sorted(draw(st.lists(st.floats(100.0, float(t[-1])), max_size=4, unique=True)))
    sizes = draw(st.lists(st.integers(1, 30), max_size=60))
    return t, d, cycles, sizes


@settings(max_examples=60, deadline=None)
@given(displacement_streams())
def test_indicator_and_episodes_are_chunk_invariant(stream):
    t, d, ends, sizes = stream
    params = CompensationParams()

    def make():
        ind = Indicator(params)
        prev = 95.0
        for e in ends:  # cycle [prev, e): tolerated 0.2 × duration from e on
            ind.cycle_completed(prev, e)
            prev = e
        return ind

    whole_codes, whole_changes = make().update(t, d)
    codes, changes = feed(make(), t, d, sizes)
    np.testing.assert_array_equal(codes, whole_codes)
    assert changes == whole_changes

    def tolerated(ti):
        val, prev = 1.0, 95.0
        for e in ends:
            if ti >= e:
                val = 0.2 * (e - prev)
            prev = e
        return val

    np.testing.assert_array_equal(whole_codes, reference_codes(t, d, 0.1, tolerated, 0.25))
    # changes: exactly the known samples whose state differs from the previous known one
    known = whole_codes >= 0
    kc, kt = whole_codes[known], t[known]
    idx = [i for i in range(kc.size) if i == 0 or kc[i] != kc[i - 1]]
    assert whole_changes == [(kt[i], STATE_NAMES[kc[i]]) for i in idx]
    # episodes: same for any chunking, and exactly the outside runs that reached warning
    tr, eps, i = EpisodeTracker(params), [], 0
    for s in [*sizes, t.size]:
        eps += tr.update(t[i : i + s], whole_codes[i : i + s], d[i : i + s])
        i += s
    eps += tr.flush()
    tr2 = EpisodeTracker(params)
    whole_ep = tr2.update(t, whole_codes, d) + tr2.flush()
    assert eps == whole_ep
    for ep in whole_ep:
        # the run's samples: [start, end), end being the next sample's time, or the last
        # sample's when the run was still going at the end (flush)
        inside = (t >= ep.start) & (t < ep.end)
        inside[-1] |= ep.end == t[-1] and whole_codes[-1] >= OUTSIDE
        assert (whole_codes[inside] >= OUTSIDE).all() and (whole_codes[inside] == WARNING).any()
        assert ep.duration_s == ep.end - ep.start
        assert ep.max_displacement_m == np.nanmax(d[inside])


def test_episodes_report_long_runs_only():
    t, d = _profile()
    codes, _ = Indicator().update(t, d)
    tr = EpisodeTracker()
    eps = tr.update(t[:150], codes[:150], d[:150])  # the 2.5 s run ends at 6.5 s = sample 162
    assert eps == []
    eps = tr.update(t[150:], codes[150:], d[150:]) + tr.flush()
    assert len(eps) == 1
    ep = eps[0]
    assert ep.start == t[t >= 4.0][0] and ep.end == t[t >= 6.5][0]
    assert ep.duration_s == pytest.approx(2.5, abs=1 / FS)
    assert ep.max_displacement_m == 0.15


def test_state_names():
    assert [state_name(c) for c in (OK, OUTSIDE, WARNING, UNKNOWN)] == [
        "ok",
        "outside",
        "warning",
        None,
    ]


# ----------------------------------------------------------------------------- verdicts


def brute_force(t, codes, start, end, hold, dt=1e-4):
    """Outside and known time of [start, end) by sampling the held state on a fine grid."""
    tau = np.arange(start, end, dt) + dt / 2
    i = np.searchsorted(t, tau, side="right") - 1
    valid = i >= 0
    ii = np.maximum(i, 0)
    nxt = np.append(t[1:], np.inf)[ii]
    held = valid & (tau < np.minimum(nxt, t[ii] + hold))
    c = codes[ii]
    return float(np.sum(held & (c >= 1)) * dt), float(np.sum(held & (c >= 0)) * dt)


def _judge_stream(seed=0):
    rng = np.random.default_rng(seed)
    dt = rng.uniform(0.03, 0.05, 1500)  # ~25 Hz with jitter, 60 s ...
    dt[rng.choice(1500, 4, replace=False)] = 0.8  # ... and data gaps longer than max_hold_s
    t = np.cumsum(dt)
    codes = np.zeros(t.size, dtype=np.int8)
    for _ in range(12):  # outside runs of various lengths
        a = rng.integers(0, t.size - 80)
        codes[a : a + rng.integers(5, 80)] = rng.choice([OUTSIDE, WARNING])
    unknown = (t > 20.0) & (t < 22.5)  # 2.5 s without estimate
    codes[unknown] = UNKNOWN
    d = np.where(codes == UNKNOWN, np.nan, np.where(codes >= 1, 0.15, 0.04))
    d = d + rng.uniform(0, 0.01, t.size)
    bounds = list(np.cumsum(rng.uniform(3.0, 7.0, 12)) + 1.0)
    return t, codes, d, [float(b) for b in bounds if b < t[-1]]


def test_verdicts_match_brute_force():
    t, codes, d, bounds = _judge_stream()
    params = CompensationParams()
    verdicts = CycleJudge(params).update(t, codes, bounds, d)
    assert [(v.start, v.end) for v in verdicts] == list(itertools.pairwise(bounds))
    judged = 0
    for v in verdicts:
        out_s, known_s = brute_force(t, codes, v.start, v.end, params.max_hold_s)
        dur = v.end - v.start
        assert v.outside_s == pytest.approx(out_s, abs=5e-4)
        assert v.outside_fraction == pytest.approx(out_s / dur, abs=1e-4)
        assert v.coverage == pytest.approx(known_s / dur, abs=1e-4)
        if v.coverage < 0.8:
            assert v.compensatory is None
        else:
            judged += 1
            assert v.compensatory == (v.outside_fraction > 0.2)
        m = (t >= v.start) & (t < v.end) & (codes >= 0)
        assert v.max_displacement_m >= np.max(d[m])
    assert judged >= 8
    assert any(v.compensatory for v in verdicts) and any(v.compensatory is False for v in verdicts)
    assert any(v.compensatory is None for v in verdicts)  # the cycle with 2.5 s unknown


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 40), max_size=80), st.integers(0, 25), st.integers(0, 3))
def test_verdicts_are_chunk_and_arrival_invariant(sizes, delay, seed):
    """Any chunking, and boundaries handed over up to ``delay`` chunks after the data has
    reached them (at most 4 s late, within history_s)."""
    t, codes, d, bounds = _judge_stream(seed)
    whole = CycleJudge().update(t, codes, bounds, d)
    edges = np.unique(np.clip(np.cumsum([0, *sizes]), 0, t.size)).tolist()
    chunks = list(itertools.pairwise(edges))
    if edges[-1] < t.size:
        chunks.append((edges[-1], t.size))
    deliver: dict[int, list[float]] = {}
    n_prev = 0
    for x in bounds:
        due = next(n for n, (_, b) in enumerate(chunks) if t[b - 1] >= x)
        n = max(due, n_prev)
        while n < min(due + delay, len(chunks) - 1) and t[chunks[n + 1][0]] - x <= 4.0:
            n += 1
        deliver.setdefault(n, []).append(x)
        n_prev = n
    judge, got = CycleJudge(), []
    for n, (a, b) in enumerate(chunks):
        got += judge.update(t[a:b], codes[a:b], deliver.get(n, []), d[a:b])
    assert got == whole


def test_verdict_threshold_is_strict():
    t = np.arange(750) / 25.0  # exact 25 Hz grid, 30 s
    codes = np.zeros(t.size, dtype=np.int8)
    codes[150:174] = OUTSIDE  # 24 samples in [5, 10): 0.96 s = 19.2 %
    codes[250:276] = WARNING  # 26 samples in [10, 15): 1.04 s = 20.8 %
    codes[400:450] = UNKNOWN  # 2 s of [15, 20) unknown: coverage 60 %
    v = CycleJudge().update(t, codes, [5.0, 10.0, 15.0, 20.0])
    assert [x.outside_fraction for x in v] == pytest.approx([0.192, 0.208, 0.0])
    assert [x.compensatory for x in v] == [False, True, None]
    assert [x.coverage for x in v] == pytest.approx([1.0, 1.0, 0.6])
    assert all(math.isnan(x.max_displacement_m) for x in v)  # no displacement given
    strict = CycleJudge(CompensationParams(max_outside_fraction=0.1, min_coverage=0.5))
    assert [x.compensatory for x in strict.update(t, codes, [5.0, 10.0, 15.0, 20.0])] == [
        True,
        True,
        False,
    ]


def test_judge_respects_cycle_start_and_max_cycle():
    t = np.arange(0.0, 80.0, 1 / FS)
    codes = np.zeros(t.size, dtype=np.int8)
    bs = [Boundary(5.0), Boundary(10.0, 5.0), Boundary(15.0), Boundary(20.0, 15.0)]
    v = CycleJudge().update(t, codes, bs)
    assert [(x.start, x.end) for x in v] == [(5.0, 10.0), (15.0, 20.0)]
    assert all(x.source == "path" and x.compensatory is False for x in v)
    # plain floats: consecutive pairs, unless longer than max_cycle_s
    v = CycleJudge(max_cycle_s=30.0).update(t, codes, [1.0, 6.0, 45.0, 50.0])
    assert [(x.start, x.end) for x in v] == [(1.0, 6.0), (45.0, 50.0)]
    # a cycle is judged only once data reaches its end
    judge = CycleJudge()
    first = judge.update(t[:100], codes[:100], [1.0, 3.0, 4.5])  # data up to 3.96 s
    assert [(x.start, x.end) for x in first] == [(1.0, 3.0)]
    assert judge.update(t[:0], codes[:0], [10.0]) == []
    later = judge.update(t[100:300], codes[100:300])
    assert [(x.start, x.end) for x in later] == [(3.0, 4.5), (4.5, 10.0)]


# ----------------------------------------------------------------------------- live paths


@settings(max_examples=60, deadline=None)
@given(
    displacement_streams(),
    st.lists(st.booleans(), min_size=1, max_size=20),
    st.sampled_from([None, 0.3]),
)
@example((*_profile(), [3.0, 7.5, 15.0], [1] * 500), [True], None)  # the live schedule
def test_rows_as_the_pipeline_passes_them_equal_one_array_call(stream, as_list, warn):
    """The Python-float paths (``t`` and displacement as lists of one row or a few, codes as
    the indicator returned them, like ``Pipeline._rows``), mixed with array chunks, give
    what one call on the whole arrays gives; every call gets its own codes array."""
    t, d, ends, sizes = stream
    params = CompensationParams(warning_after_s=warn)
    bounds = [Boundary(e, s) for s, e in itertools.pairwise([t[0] - 5.0, *ends])]
    ind, judge, tr = Indicator(params), CycleJudge(params), EpisodeTracker(params)
    whole_codes, whole_changes = ind.update(t, d, boundaries=bounds)
    whole = (whole_changes, judge.update(t, whole_codes, bounds, d), tr.update(t, whole_codes, d))
    ind, judge, tr = Indicator(params), CycleJudge(params), EpisodeTracker(params)
    codes, changes, verdicts, eps, a = [], [], [], [], 0
    for k, s in enumerate([*sizes, t.size]):
        b = min(a + s, t.size)
        if a >= b:
            break
        # a boundary goes with the chunk that holds the first sample at or after it
        due = [x for x in bounds if (a == 0 or t[a - 1] < x) and x <= t[b - 1]]
        tt, dd = (
            (t[a:b].tolist(), d[a:b].tolist()) if as_list[k % len(as_list)] else (t[a:b], d[a:b])
        )
        c, ch = ind.update(tt, dd, boundaries=due)
        assert c.dtype == np.int8 and c.shape == (b - a,)
        changes += ch
        verdicts += judge.update(tt, c, due, dd)
        eps += tr.update(tt, c, dd)
        codes.append(c.copy())
        c[:] = 7  # the caller owns the array: later results must not see this
        a = b
    np.testing.assert_array_equal(np.concatenate(codes), whole_codes)
    assert repr((changes, verdicts, eps)) == repr(whole)  # repr: NaN fields compare equal


# ----------------------------------------------------------------------------- whole chain


def test_chain_classifies_synthetic_cycles():
    """Segmenter + indicator + judge on a loop session where the shoulder leaves the tolerance
    for 45 % of some cycles and 8 % of the others; no estimate for the first 12 s."""
    t, wrist, u, _ = loop_session(seed=7, n_cycles=16)
    bs = CycleSegmenter(CycleParams(mode="path")).update(t, wrist)
    ph = (np.angle(np.mean(np.exp(2j * np.pi * np.interp(bs, t, u)))) / (2 * np.pi)) % 1.0
    rel = u - ph
    cycle = np.floor(rel).astype(int)  # detected cycle [ph + k, ph + k + 1) has index k
    compensatory_cycles = {3, 4, 9, 13}
    frac = np.where(np.isin(cycle, list(compensatory_cycles)), 0.45, 0.08)
    outside = ((rel % 1.0) >= 0.3) & ((rel % 1.0) < 0.3 + frac)
    rng = np.random.default_rng(7)
    ang = rng.uniform(0, 2 * np.pi, t.size)
    mag = np.where(outside, rng.uniform(0.12, 0.18, t.size), rng.uniform(0.0, 0.07, t.size))
    nominal = np.array([0.0, 0.0, 1.2])
    shoulder = nominal + np.c_[mag * np.cos(ang), mag * np.sin(ang), rng.normal(0, 0.2, t.size)]
    shoulder[t < 12.0] = np.nan

    def chain(sizes):
        seg, ind, judge, tr = CycleSegmenter(), Indicator(), CycleJudge(), EpisodeTracker()
        verdicts, eps, codes, i = [], [], [], 0
        for s in [*sizes, t.size]:
            if i >= t.size:
                break
            sl = slice(i, i + s)
            d = displacement(shoulder[sl], nominal)
            b = seg.update(t[sl], wrist[sl])
            c, _ = ind.update(t[sl], d, boundaries=b)
            verdicts += judge.update(t[sl], c, b, d)
            eps += tr.update(t[sl], c, d)
            codes.append(c)
            i += s
        return verdicts, eps, np.concatenate(codes)

    verdicts, eps, codes = chain([1] * t.size)  # live: one robot sample per message
    for sizes in ([], [7] * 400, np.random.default_rng(1).integers(1, 60, 300).tolist()):
        v2, e2, c2 = chain(sizes)  # offline all at once, other chunkings: identical
        assert (v2, e2) == (verdicts, eps)
        np.testing.assert_array_equal(c2, codes)
    assert len(verdicts) == len(bs) - 1
    k_end = np.round(np.interp([v.end for v in verdicts], t, u) - ph).astype(int)
    for v, k in zip(verdicts, k_end, strict=True):
        if v.coverage < 0.8:
            assert v.start < 12.0 and v.compensatory is None
            continue
        assert v.coverage == pytest.approx(1.0)
        assert v.compensatory == (k - 1 in compensatory_cycles), (k, v)
    assert sum(v.compensatory is None for v in verdicts) >= 1  # the cycle(s) before 12 s
    assert sum(bool(v.compensatory) for v in verdicts) == len(compensatory_cycles)
    # the orange warning (tolerated = 20 % of the last cycle) only in compensatory cycles
    warn_cycles = set(np.floor(rel[codes == WARNING]).astype(int).tolist())
    assert warn_cycles == compensatory_cycles
    assert len(eps) == len(compensatory_cycles)


def test_chunked_judge_keeps_the_rows_of_a_cycle_opened_long_before():
    """A first cycle (or one after a detector restart) may open up to ``max_cycle_s`` before
    its boundary arrives: a chunked judge must still have those rows (it kept only
    ``history_s``, and judged a 19 s cycle on its last 5 s; found by hypothesis)."""
    t = 100.0 + 0.04 * np.arange(400)
    d = np.full(t.size, 0.05)
    d[50:100] = 0.15  # 2 s outside, early in the cycle
    codes, _ = Indicator(CompensationParams()).update(t, d)
    b = Boundary(115.0, 96.0)  # opened 19 s before it ends, 4 s before the data starts
    whole = CycleJudge(CompensationParams()).update(t, codes, [b], d)
    judge, chunked = CycleJudge(CompensationParams()), []
    for a in range(0, t.size, 10):
        due = [b] if t[a] <= b < t[min(a + 10, t.size) - 1] else []
        chunked += judge.update(t[a : a + 10], codes[a : a + 10], due, d[a : a + 10])
    assert len(whole) == 1 and whole[0].outside_s > 1.9
    assert repr(chunked) == repr(whole)
