"""The per-row formulas give bit-identical numbers on floats and on arrays."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators import rows

M_S, M_V = rows.SCALAR, rows.VECTOR

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
maybe = st.one_of(finite, st.just(math.nan))


def _same(scalar_out: object, vector_out: object) -> None:
    """Each scalar (row by row) equals the vector result, NaN included, bit for bit."""
    s = np.asarray(scalar_out, dtype=np.float64)
    v = np.asarray(vector_out, dtype=np.float64)
    assert s.shape == v.shape
    assert np.array_equal(s.view(np.int64), v.view(np.int64)) or np.array_equal(
        s, v, equal_nan=True
    ), (s, v)


def _quat(w: float, x: float, y: float, z: float) -> tuple[float, ...]:
    n = math.sqrt(w * w + x * x + y * y + z * z) or 1.0
    return (w / n, x / n, y / n, z / n)


quats = st.tuples(finite, finite, finite, finite).map(lambda q: _quat(*q))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            finite,  # s
            st.booleans(),  # ok
            st.tuples(
                finite,
                maybe,
                maybe,
                finite,
                st.floats(0, 1),
                st.sampled_from([0.0, 1.0]),
                st.sampled_from([0.0, 1.0, math.nan]),
                maybe,
            ),  # snapshot
            st.sampled_from([0.0, 1.0]),  # segment
            quats,
            quats,
            st.tuples(finite, finite, finite),  # elbow
            st.floats(0.2, 0.4),  # arm length
            st.tuples(maybe, finite, finite),  # nominal
        ),
        min_size=1,
        max_size=12,
    )
)
def test_scalar_rows_equal_vector(data: list[tuple]) -> None:  # type: ignore[type-arg]
    scalar = []
    for s, ok, snap, seg, q_now, q_pair, p_e, la, nom in data:
        h = rows.heading(M_S, s, ok, snap, seg)
        q_ra, x_now, x_a = rows.upper_arm(M_S, h.delta, h.good, q_now, q_pair)
        sh = rows.shoulder(p_e, x_a, la)
        scalar.append(
            (
                *h[:4],
                float(h.good),
                *q_ra,
                *x_now,
                *x_a,
                rows.angle_deg(M_S, x_now, rows.unit(M_S, p_e)),
                *rows.elevation_azimuth(M_S, x_now),
                rows.displacement(M_S, sh, nom, "3d"),
                *rows.nlerp(M_S, q_now, q_pair, 0.3),
            )
        )
    cols = list(zip(*data, strict=True))

    def arr(i: int, j: int | None = None) -> np.ndarray:
        if j is None:
            return np.array(cols[i])
        return np.array([c[j] for c in cols[i]])

    snap = tuple(arr(2, j) for j in range(8))
    q_now = tuple(arr(4, j) for j in range(4))
    q_pair = tuple(arr(5, j) for j in range(4))
    p_e = tuple(arr(6, j) for j in range(3))
    nom = tuple(arr(8, j) for j in range(3))
    with np.errstate(invalid="ignore", divide="ignore"):
        h = rows.heading(M_V, arr(0), arr(1).astype(bool), snap, arr(3))
        q_ra, x_now, x_a = rows.upper_arm(M_V, h.delta, h.good, q_now, q_pair)
        sh = rows.shoulder(p_e, x_a, arr(7))
        vector = np.column_stack(
            (
                *h[:4],
                h.good.astype(float),
                *q_ra,
                *x_now,
                *x_a,
                rows.angle_deg(M_V, x_now, rows.unit(M_V, p_e)),
                *rows.elevation_azimuth(M_V, x_now),
                rows.displacement(M_V, sh, nom, "3d"),
                *rows.nlerp(M_V, q_now, q_pair, np.full(len(data), 0.3)),
            )
        )
    _same(scalar, vector)


def test_nothing_raises_on_nan_and_zero() -> None:
    """Both branches of every ``where`` are evaluated: NaN, ±inf std and zero vectors pass."""
    nan4 = (math.nan,) * 4
    h = rows.heading(M_S, 1.0, False, (math.nan,) * 8, 0.0)
    assert math.isnan(h.delta) and h.confidence == 0.0 and not h.good
    q_ra, x_now, x_a = rows.upper_arm(M_S, h.delta, h.good, nan4, nan4)
    assert all(math.isnan(v) for v in (*q_ra, *x_now, *x_a))
    assert all(math.isnan(v) for v in rows.unit(M_S, (0.0, 0.0, 0.0)))
    assert math.isnan(rows.angle_deg(M_S, x_now, (1.0, 0.0, 0.0)))
    assert all(math.isnan(v) for v in rows.extrapolate(M_S, x_now, x_now, 0.0, 0.1))


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=20),
    st.sampled_from([rows.TWO_PI, 1.0, 360.0, -rows.TWO_PI]),
)
def test_mod_is_pythons_percent(xs: list[float], m: float) -> None:
    """``%`` on arrays (np.remainder) equals Python's on floats: negative, huge, ±0, inf."""
    _same([M_S.mod(x, m) for x in xs], M_V.mod(np.array(xs), m))


wild = st.one_of(finite, st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e300]))


@settings(max_examples=300, deadline=None)
@given(
    wild,  # s
    st.booleans(),  # ok
    st.tuples(
        wild,
        wild,
        wild,
        wild,
        wild,
        st.sampled_from([0.0, 1.0, math.nan]),
        st.sampled_from([0.0, 1.0, math.nan]),
        wild,
    ),
    st.sampled_from([0.0, 1.0]),  # segment
    quats,
    st.one_of(quats, st.just((math.nan,) * 4)),
)
def test_fused_heading_arm_equals_generic(
    s: float,
    ok: bool,
    snap: tuple[float, ...],
    seg: float,
    q_now: tuple[float, ...],
    q_pair: tuple[float, ...],
) -> None:
    """The live row's fused form equals heading() then upper_arm() bit for bit, on floats
    and on arrays, whatever the snapshot holds (NaN, ±inf, updates in the future)."""
    h, q_ra, x_now, x_a = rows.heading_arm_scalar(s, ok, snap, seg, q_now, q_pair)
    fused = (*h[:4], float(h[4]), *q_ra, *x_now, *x_a)
    hs = rows.heading(M_S, s, ok, snap, seg)
    generic = (
        *hs[:4],
        float(hs.good),
        *(v for part in rows.upper_arm(M_S, hs.delta, hs.good, q_now, q_pair) for v in part),
    )
    _same(fused, generic)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        hv = rows.heading(
            M_V, np.array([s]), np.array([ok]), tuple(np.array([v]) for v in snap), np.array([seg])
        )
        parts = rows.upper_arm(
            M_V,
            hv.delta,
            hv.good,
            tuple(np.array([v]) for v in q_now),
            tuple(np.array([v]) for v in q_pair),
        )
    vector = np.concatenate(
        [
            *(np.asarray(v, dtype=float) for v in hv[:4]),
            hv.good.astype(float),
            *(v for part in parts for v in part),
        ]
    )
    _same(fused, vector)


vec3 = st.tuples(wild, wild, wild)


@settings(max_examples=300, deadline=None)
@given(vec3, vec3, vec3, vec3, vec3, st.sampled_from(["horizontal", "3d"]))
def test_fused_angles_equal_generic(
    x_now: tuple[float, ...],
    x_c: tuple[float, ...],
    p_e: tuple[float, ...],
    sh: tuple[float, ...],
    nom: tuple[float, ...],
    norm: str,
) -> None:
    """The live row's fused angles equal the generic functions bit for bit (NaN, ±inf, a
    nominal point on the elbow, vectors off the unit sphere)."""
    fused = rows.angles_scalar(x_now, x_c, p_e, sh, nom, norm)
    generic = (
        rows.angle_deg(M_S, x_now, x_c),
        rows.displacement(M_S, sh, nom, norm),
        rows.conventional_angle(M_S, p_e, nom, x_c),
        *rows.elevation_azimuth(M_S, x_now),
    )
    _same(fused, generic)
    col = [tuple(np.array([v]) for v in x) for x in (x_now, x_c, p_e, sh, nom)]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        vector = np.concatenate(
            [
                rows.angle_deg(M_V, col[0], col[1]),
                rows.displacement(M_V, col[3], col[4], norm),
                rows.conventional_angle(M_V, col[2], col[4], col[1]),
                *rows.elevation_azimuth(M_V, col[0]),
            ]
        )
    _same(fused, vector)


@settings(max_examples=300, deadline=None)
@given(
    st.one_of(quats, st.tuples(wild, wild, wild, wild)),
    st.one_of(quats, st.tuples(wild, wild, wild, wild)),
    st.one_of(st.floats(0.0, 1.0), wild),
)
def test_fused_nlerp_equals_generic(a: tuple[float, ...], b: tuple[float, ...], s: float) -> None:
    """Antipodal pairs, NaN, ±inf, zero and off-sphere quaternions, any weight."""
    fused = rows.nlerp_scalar(a, b, s)
    _same(fused, rows.nlerp(M_S, a, b, s))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        col = rows.nlerp(M_V, [np.array([v]) for v in a], [np.array([v]) for v in b], np.array([s]))
    _same(fused, np.concatenate(col))


@settings(max_examples=300, deadline=None)
@given(
    st.one_of(quats, st.tuples(wild, wild, wild, wild)),
    vec3,
    vec3,
    st.one_of(st.floats(0.0, 0.05), wild),
)
def test_fused_predict_equals_generic(
    q: tuple[float, ...], w: tuple[float, ...], dw: tuple[float, ...], dt: float
) -> None:
    fused = rows.predict_scalar(q, w, dw, dt)
    _same(fused, rows.predict(M_S, q, w, dw, dt))
    arr = [[np.array([v]) for v in x] for x in (q, w, dw)]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        col = rows.predict(M_V, *arr, np.array([dt]))
    _same(fused, np.concatenate(col))


@settings(max_examples=300, deadline=None)
@given(vec3)
def test_fused_unit_equals_generic(v: tuple[float, float, float]) -> None:
    fused = rows.unit_scalar(*v)
    _same(fused, rows.unit(M_S, v))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        col = rows.unit(M_V, tuple(np.array([x]) for x in v))
    _same(fused, np.concatenate(col))
