"""``report.json``'s exact text, the one encoder of both modes' reports (``rehab analyze`` and
the live service write the same bytes). Its own module so that the wearable mode's analysis
does not import the robot pipeline to write its report."""

from __future__ import annotations

from typing import Any

import numpy as np
import orjson

_REPORT_OPTS = orjson.OPT_INDENT_2 | orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS


def dump_report(report: dict[str, Any]) -> str:
    """``report.json``'s exact text: orjson, indented (the standard library's encoder is pure
    Python once indenting, ~7× slower on a report's per-cycle paths). A non-finite float is
    null (the reports hold none)."""
    return orjson.dumps(report, option=_REPORT_OPTS, default=_json_default).decode()


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)
