"""The fuzz benchmark, shorter (benchmarks/fuzz.py: the service in its own process, hostile
payloads on random and real keys beside a valid device's session, then a flood of the
largest messages on 20 names)."""

from __future__ import annotations

from benchmarks.fuzz import run


def test_hostile_payloads_and_flood() -> None:
    # the flood's names not admitted, as by default (admitted, each gets a pipeline: the
    # figures of that case are in docs/benchmarks.md)
    out = run(payloads=3000, flood_s=6.0, seed=2, duration_s=30.0, admit_flood=False)
    assert out["alive"], out  # 0 crashes
    assert out["valid_accepted"] == out["valid_messages"], out
    assert out["estimates_equal"], out  # the valid device's numbers are undisturbed
    assert out["health_failures"] == 0, out
    assert out["health_worst_ms"] < 1000, out  # the API answered within 1 s throughout
    assert out["rss_after_fuzz_mib"] - out["rss_warm_mib"] < 100, out  # memory flat
    assert out["rss_settled_mib"] - out["rss_before_flood_mib"] < 100, out  # and after the flood
