"""The fuzz benchmark, shorter (benchmarks/fuzz.py: the service in its own process, hostile
payloads on random and real keys beside a valid device's session, then a flood of the
largest messages on 20 names), in both modes of ``rehab serve``."""

from __future__ import annotations

from typing import Any

from benchmarks.fuzz import FLAT_MIB, run


def _check(out: dict[str, Any]) -> None:
    assert out["alive"], out  # 0 crashes
    assert out["valid_accepted"] == out["valid_messages"], out
    assert out["estimates_equal"], out  # the valid device's numbers are undisturbed
    assert out["health_failures"] == 0, out
    assert out["health_worst_ms"] < 1000, out  # the API answered within 1 s throughout
    assert out["rss_after_fuzz_mib"] - out["rss_warm_mib"] < FLAT_MIB, out  # memory flat
    assert out["rss_settled_mib"] - out["rss_before_flood_mib"] < FLAT_MIB, out  # after too


def test_hostile_payloads_and_flood() -> None:
    # one process; the flood's names not admitted, as by default
    _check(run(payloads=3000, flood_s=6.0, seed=2, duration_s=30.0, admit_flood=False))


def test_hostile_payloads_and_flood_workers() -> None:
    # --workers 2 (the API node and two workers, their memory summed); the flood's names
    # admitted: each gets a pipeline in a worker, and the flood reaches the pipelines
    _check(run(payloads=3000, flood_s=6.0, seed=3, duration_s=30.0, workers=2))
