"""What a poll returns (:mod:`estimators.output`): the row matrix's layout, joining polls."""

from __future__ import annotations

import numpy as np

from estimators.output import (
    NCOL,
    ROW_COLUMNS,
    SPAN,
    Output,
    Quality,
    RowTable,
    column_index,
    concat_rows,
)


def _table(n: int, first: float = 0.0) -> RowTable:
    m = first + np.arange(n * NCOL, dtype=np.float64).reshape(n, NCOL) / 100.0
    return RowTable(m, np.arange(n, dtype=np.int8) % 3)


def test_layout_covers_the_matrix_once() -> None:
    assert list(SPAN) == list(ROW_COLUMNS)
    assert sorted(i for a, w in SPAN.values() for i in range(a, a + w)) == list(range(NCOL))


def test_columns_are_slices_of_the_matrix() -> None:
    r = _table(3)
    assert list(r) == list(ROW_COLUMNS) and len(r) == len(ROW_COLUMNS)
    assert r["t"].tolist() == r.m[:, 0].tolist()
    assert r["elbow"].shape == (3, 3) and r["q_ra"].shape == (3, 4)
    assert r["state"].tolist() == [0, 1, 2]
    assert r["heading_converged"].dtype == bool
    a, w = SPAN["nominal_shoulder"]
    assert np.array_equal(r["nominal_shoulder"], r.m[:, a : a + w])
    idx = column_index(["t", "elbow"])
    assert idx.tolist() == [0, 1, 2, 3]
    assert r.column_lists(idx) == r.m[:, :4].T.tolist()


def test_polls_join_in_order() -> None:
    a, b = _table(2), _table(3, first=1000.0)
    joined = concat_rows([a, b])
    assert isinstance(joined, RowTable)
    assert np.array_equal(joined["wrist"], np.concatenate([a["wrist"], b["wrist"]]))
    assert joined["state"].tolist() == [0, 1, 0, 1, 2]
    out = Output()
    out.extend(Output())
    assert out.n == 0
    out.extend(Output(a, [{"t": 0.0, "type": "state", "state": "ok"}]))
    out.extend(Output(b, [{"t": 1.0, "type": "state", "state": "outside"}]))
    assert out.n == 5
    assert np.array_equal(out.rows["t"], joined["t"])
    assert [f["state"] for f in out.feedback] == ["ok", "outside"]
    a.m[0, 0] = -1.0  # the first poll's rows were copied, not kept
    assert out.rows["t"][0] == 0.0


def test_quality_report_is_sorted_and_bounded() -> None:
    q = Quality()
    q.reject("time_backwards")
    q.reject("duplicate_t", 2)
    q.reject("time_backwards")
    q.gaps.extend({"stream": "imu", "t": float(i), "duration_s": 1.0} for i in range(1500))
    d = q.as_dict()
    assert list(d["rejected"].items()) == [("duplicate_t", 2), ("time_backwards", 2)]
    assert len(d["gaps"]) == 1000
