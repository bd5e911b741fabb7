"""The live loop's cheap paths give exactly what the simple ones give: estimate blocks as
Python lists (a poll's few rows) or numpy arrays (many rows) serialise to the same text, and
the shoulder rows filtered in batches give the same "nominal from the estimate"."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from backend.live import feed
from backend.live.devices import DeviceStats
from backend.live.run import SHOULDER_MEMORY, LiveRun
from estimators.output import NCOL, SPAN, RowTable

SPECIAL = [0.0, -0.0, 1e-7, 1e16, 1e300, 5e-324, 0.1, 1 / 3, np.nan, np.inf, -np.inf]


def random_rows(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    pool = np.concatenate([rng.normal(size=64) * 10.0 ** rng.integers(-8, 8, size=64), SPECIAL])
    m = rng.choice(pool, size=(n, 19))
    return {
        "t": m[:, 0],
        "elbow": m[:, 1:4],
        "shoulder": m[:, 4:7],
        "elbow_angle_deg": m[:, 7],
        "heading_offset_deg": m[:, 8],
        "shoulder_displacement_m": m[:, 9],
        "upper_arm_elevation_deg": m[:, 10],
        "upper_arm_azimuth_deg": m[:, 11],
        "heading_confidence": m[:, 12],
        "nominal_shoulder": m[:, 13:16],
        "wrist": m[:, 16:19],
        "heading_converged": rng.random(n) > 0.5,
        "state": rng.integers(-1, 3, size=n).astype(np.int8),
    }


def texts(groups: list[Any]) -> tuple[Any, ...]:
    with np.errstate(invalid="ignore"):  # inf - inf in the overlay's offsets
        return _texts(groups)


def _texts(groups: list[Any]) -> tuple[Any, ...]:
    out: list[Any] = []
    for display in (False, True):
        blocks = [feed.estimate_block(r, display=display) for r in groups]
        out.append([feed.dumps(b.columns(len(feed.CONTRACT_FLOATS))) for b in blocks])
        joined = feed.join(blocks)
        out.append(feed.dumps({"rows": joined.columns()}))
        out.append(feed.as_rows(joined))
    overlay = feed.join([feed.overlay_block(r) for r in groups])
    out.append(feed.dumps(overlay.columns()))
    out.append(feed.as_rows(overlay))
    return tuple(out)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_list_and_array_blocks_give_the_same_text(seed: int) -> None:
    rng = np.random.default_rng(seed)
    groups = [random_rows(rng, int(n)) for n in rng.integers(1, 90, size=rng.integers(1, 4))]
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(feed, "LIST_ROWS", 10**9)
        as_lists = texts(groups)
        mp.setattr(feed, "LIST_ROWS", 0)
        as_arrays = texts(groups)
        mp.setattr(feed, "LIST_ROWS", 40)  # mixed: some blocks of each kind
        mixed = texts(groups)
    finally:
        mp.undo()
    assert as_lists == as_arrays == mixed


def test_block_columns_are_the_contract_then_the_dashboard() -> None:
    rows = random_rows(np.random.default_rng(1), 2)
    cols = feed.estimate_block(rows, display=True).columns()
    assert list(cols) == [*feed.CONTRACT_FLOATS, *feed.DISPLAY_EXTRA, "heading_converged", "state"]
    assert cols["heading_converged"] == rows["heading_converged"].astype(int).tolist()


def reference_shoulder(blocks: list[tuple[np.ndarray, np.ndarray]]) -> list[float] | None:
    if not blocks:
        return None
    sh = np.concatenate([b[0] for b in blocks])
    ok = np.isfinite(sh).all(axis=1) & np.concatenate([b[1] for b in blocks]).astype(bool)
    kept = sh[ok]
    if not len(kept):
        return None
    return [float(x) for x in np.mean(kept[-SHOULDER_MEMORY:], axis=0)]


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_shoulder_estimate_from_batched_rows(seed: int) -> None:
    rng = np.random.default_rng(seed)
    live = LiveRun("d", "rehab", DeviceStats("d"))
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(120):
        n = int(rng.integers(1, 4))
        sh = rng.normal(size=(n, 3))
        sh[rng.random(n) < 0.2, int(rng.integers(0, 3))] = np.nan
        conv = rng.random(n) < 0.7
        live._keep_shoulders(sh, conv)
        seen.append((sh, conv))
        if rng.random() < 0.1:
            assert live.shoulder_estimate() == reference_shoulder(seen)
        kept = sum(len(b) for b in live._shoulders)
        assert live._unsorted_rows < 64 and kept < SHOULDER_MEMORY + 64 + 4  # bounded
    assert live.shoulder_estimate() == reference_shoulder(seen)


def as_table(rows: dict[str, np.ndarray]) -> RowTable:
    """The same rows as the pipeline hands them over: one matrix behind a mapping."""
    n = len(rows["t"])
    m = np.full((n, NCOL), np.nan)
    for name, (a, w) in SPAN.items():
        if name in rows and name != "state":
            m[:, a : a + w] = np.asarray(rows[name], dtype=np.float64).reshape(n, w)
    return RowTable(m, rows["state"])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_row_table_blocks_give_the_same_text(seed: int) -> None:
    rng = np.random.default_rng(seed)
    groups = [random_rows(rng, int(n)) for n in rng.integers(1, 90, size=rng.integers(1, 4))]
    assert texts([as_table(r) for r in groups]) == texts(groups)
