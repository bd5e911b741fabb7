"""The WebSocket messages are defined once (backend/schemas/live.py); the front end's types
are generated from the JSON Schema file this test keeps current."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from backend.live import feed
from backend.schemas import live

SCHEMA = Path(__file__).resolve().parents[2] / "frontend/src/lib/live-messages.schema.json"


def test_the_front_ends_schema_file_is_the_models() -> None:
    assert SCHEMA.read_text() == live.schema_text(), (
        "run `python -m backend.schemas.live > frontend/src/lib/live-messages.schema.json`"
    )


def test_the_builders_make_the_models_messages() -> None:
    state = feed.state_message("d1", 12.5, "outside")
    cycle = feed.cycle_message(
        "d1", {"start": 1.0, "end": 4.0, "outside_fraction": 0.3, "compensatory": True}, 7
    )
    for m in (state, cycle):
        assert live.LIVE.validate_python(m, strict=True) == m
        assert live.OVERLAY.validate_python(m, strict=True) == m


def test_a_key_more_or_less_is_refused() -> None:
    ok = {"type": "state", "device": "d1", "t": 1.0, "state": "ok"}
    live.LIVE.validate_python(ok, strict=True)
    for bad in (
        {**ok, "extra": 1},
        {k: v for k, v in ok.items() if k != "t"},
        {**ok, "state": "maybe"},
        {**ok, "type": "unknown"},
    ):
        with pytest.raises(ValidationError):
            live.LIVE.validate_python(bad, strict=True)
