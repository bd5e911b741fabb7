"""Arbitrary timestamps never crash anything nor blind a device, offline (``rehab analyze``)
and live (the service's per-device run): a far-future glitch, NaN, huge, negative, jumps,
and a clock that restarts (backend.clock_guard)."""

from __future__ import annotations

import math
import resource
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from backend.analysis import analyze
from backend.clock_guard import CONFIRM, NEAR_S, ClockGuard, Verdict
from backend.live.devices import DeviceStats
from backend.live.ingest import RawMessage
from backend.live.run import LiveRun
from estimators.params import PipelineParams
from protocol import recording, wire
from simulator import SimConfig, simulate

DEV = "clk01"
Raw = list[tuple[str, dict[str, Any]]]


@cache
def raw() -> Raw:
    return list(simulate(SimConfig(seed=5, duration_s=20.0, device=DEV)).messages)


def run_offline(tmp: Path, messages: Raw, name: str) -> tuple[list[str], dict[str, Any]]:
    path = tmp / f"{name}.jsonl.gz"
    recording.write(path, messages)
    run, rep = analyze(path, PipelineParams())
    return run.est_lines, rep


@cache
def undisturbed(tmp: Path) -> tuple[list[str], dict[str, Any]]:
    return run_offline(tmp, raw(), "clean")


def glitch(t: float, kind: str) -> tuple[str, dict[str, Any]]:
    if kind == "imu":
        return f"rehab/{DEV}/imu/upperarm", {"t": [t], "gyr": [[0, 0, 0]], "acc": [[0, 0, 9.8]]}
    if kind == "robot":
        return f"rehab/{DEV}/robot", {
            "t": [t],
            "wrist": [[0.3, 0.4, 0.1]],
            "proximal": [[0.3, 0.2, 0.1]],
        }
    return f"rehab/{DEV}/event", {"t": t, "type": "shoulder_reference", "point": [0, 0, 0]}


def newest_before(messages: Raw, i: int) -> float:
    return max(float(np.max(p["t"])) for k, p in messages[:i] if not k.endswith("/event"))


@pytest.fixture(scope="module")
def tmp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("clock")


def test_far_future_stamp_costs_one_rejection_offline(tmp: Path) -> None:
    """The finding: t = 1e9 made analyze allocate 186 GiB and crash."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    messages = raw()
    i = len(messages) // 2
    bad = [*messages[:i], glitch(1e9, "imu"), *messages[i:]]
    resource.setrlimit(resource.RLIMIT_AS, (8 << 30, hard))  # a 186 GiB array fails fast
    try:
        est, rep = run_offline(tmp, bad, "future")
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    clean_est, _ = undisturbed(tmp)
    assert est == clean_est
    assert rep["data_quality"]["rejected"] == {"time_jump": 1}  # was: 186 GiB, a traceback


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    t=st.one_of(finite, st.sampled_from([1e9, -1e9, 0.0, -0.0, 1e308, -1e308, 5e-324])),
    kind=st.sampled_from(["imu", "robot", "event"]),
    where=st.floats(0.05, 0.95),
)
def test_one_message_with_any_stamp_offline(tmp: Path, t: float, kind: str, where: float) -> None:
    messages = raw()
    i = int(len(messages) * where)
    est, rep = run_offline(tmp, [*messages[:i], glitch(t, kind), *messages[i:]], "one")
    clean_est, _ = undisturbed(tmp)
    ref = newest_before(messages, i)
    if abs(t - ref) > (60.0 if kind == "event" else NEAR_S):
        # far: rejected and counted; the device's numbers are those of the undisturbed run
        assert est == clean_est
        rejected = rep["data_quality"]["rejected"]
        assert rejected.get("time_jump", 0) + rejected.get("time_backwards", 0) == 1
    else:
        # near: the pipeline's own ordering rules; never blinded for longer than NEAR_S
        last_t = float(clean_est[-1].split(",", 1)[0])
        assert float(est[-1].split(",", 1)[0]) == last_t
        assert len(est) >= len(clean_est) - 2 * NEAR_S * 25 - 1


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    offset=st.one_of(
        st.floats(-1e9, 1e9).filter(lambda x: abs(x) > NEAR_S + 0.1),
        st.sampled_from([-20.0, -10.0, 1e9, -1e9, 3.0, 3000.0, 7200.0]),
    ),
    where=st.floats(0.2, 0.6),
)
def test_clock_that_jumps_or_restarts_offline(tmp: Path, offset: float, where: float) -> None:
    """From some message on, every stamp is shifted (a restart: negative offsets back to
    and below 0, an NTP step, a jump): after at most CONFIRM messages the device is seen
    again, on its new time base."""
    messages = raw()
    i = int(len(messages) * where)

    def shifted(p: dict[str, Any]) -> dict[str, Any]:
        t = p["t"]
        return {**p, "t": [x + offset for x in t] if isinstance(t, list) else t + offset}

    moved = [(k, shifted(p)) for k, p in messages[i:]]
    est, rep = run_offline(tmp, [*messages[:i], *moved], "shift")
    robot = [p["t"] for k, p in moved if k.endswith("/robot")]
    t_rows = [float(ln.split(",", 1)[0]) for ln in est]
    assert t_rows and t_rows[-1] == robot[-1][-1], "the device was blinded"
    first_new = robot[0][0]
    rows_after = sum(1 for t in t_rows if abs(t - first_new) <= 30.0 and t >= first_new)
    lost = (CONFIRM + 1) * max(map(len, robot))
    assert rows_after >= sum(map(len, robot)) - lost
    rejected = rep["data_quality"]["rejected"]
    assert rejected.get("time_jump", 0) + rejected.get("time_backwards", 0) <= CONFIRM + 1


def live_rows(messages: Raw) -> tuple[list[float], DeviceStats]:
    stats = DeviceStats(DEV)
    run = LiveRun(DEV, "rehab", stats)
    rows: list[float] = []
    for k, p in messages:
        payload = wire.dumps(p) if all(_finite(p)) else recording_text(p)
        run.ingest(RawMessage(k, payload, len(payload), 0.0, k.split("/")[2]))
        out = run.poll()
        if out is not None and out.n:
            rows.extend(out.rows["t"].tolist())
    return rows, stats


def _finite(p: dict[str, Any]) -> list[bool]:
    t = p["t"]
    return [math.isfinite(x) for x in (t if isinstance(t, list) else [t])]


def recording_text(p: dict[str, Any]) -> bytes:
    import json

    return json.dumps(p).encode()  # NaN as the literal NaN: not JSON, rejected by the decoder


@settings(max_examples=25, deadline=None)
@given(
    stamps=st.lists(
        st.one_of(finite, st.just(math.nan), st.just(math.inf), st.sampled_from([1e9, -1e9])),
        min_size=1,
        max_size=5,
    ),
    where=st.floats(0.1, 0.9),
)
def test_hostile_stamps_live(stamps: list[float], where: float) -> None:
    """The live run (what each device's worker feeds): glitches never stop the rows."""
    messages = raw()
    i = int(len(messages) * where)
    bad = [glitch(t, kind) for t, kind in zip(stamps, ["imu", "robot", "event"] * 2, strict=False)]
    rows, stats = live_rows([*messages[:i], *bad, *messages[i:]])
    robot_t = [x for k, p in messages if k.endswith("/robot") for x in p["t"]]
    assert rows and max(rows) >= robot_t[-1] - 0.5, "the device was blinded"
    assert stats.pipeline_errors == 0


def test_guard_verdicts() -> None:
    g = ClockGuard()
    assert g.stream(10.0, 10.1) is Verdict.FEED
    assert g.stream(1e9, 1e9) is Verdict.REJECT  # a glitch
    assert g.stream(10.2, 10.3) is Verdict.FEED
    assert g.stream(40.0, 40.1) is Verdict.REJECT  # a pause of 30 s: the first after it
    assert g.stream(40.2, 40.3) is Verdict.FEED  # confirmed: a gap for the pipeline
    verdicts = [g.stream(float(k), k + 0.01) for k in range(CONFIRM)]  # restarted at 0
    assert verdicts == [Verdict.REJECT] * (CONFIRM - 1) + [Verdict.RESET]
    assert g.ref == CONFIRM - 1 + 0.01
    assert g.stream(math.nan, 1.0) is Verdict.REJECT
    assert not g.event(math.inf) and not g.event(1e9) and g.event(g.ref)
