"""``rehab evaluate`` of a wearable analysis (contract §8's joints.csv) against the truth.csv
of ``rehab simulate --mode wearable``: the paper's tables (Alizadegan & Behzadipour 2016,
Tables 6 and 8–10), RMSE and peak error per joint angle, and the elbow's and wrist's
position errors.

Errors are taken at each joints.csv row against the truth interpolated at its time, over
the rows where the angle is available (an empty cell is no error: it is counted apart as
``missing``), after the start's rest window (``--skip``, 2 s by default: contract §8
"Start").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from backend.analysis_wearable import read_joints
from protocol.wire import JOINT_COLUMNS

ANGLES = JOINT_COLUMNS[1:6]
POINTS = {"elbow": JOINT_COLUMNS[6:9], "wrist": JOINT_COLUMNS[9:12]}
JOINTS_NAME = "joints.csv"


def is_wearable_analysis(analysis_dir: str | Path) -> bool:
    return (Path(analysis_dir) / JOINTS_NAME).exists()


def _errors(e: np.ndarray) -> dict[str, float | int | None]:
    n_missing = int((~np.isfinite(e)).sum())
    e = e[np.isfinite(e)]
    if not len(e):
        return {"n": 0, "missing": n_missing, "rmse": None, "peak": None}
    return {
        "n": len(e),
        "missing": n_missing,
        "rmse": float(np.sqrt(np.mean(e**2))),
        "peak": float(np.max(np.abs(e))),
    }


def evaluate(
    analysis_dir: str | Path, truth_csv: str | Path, skip_s: float = 2.0
) -> dict[str, Any]:
    est = read_joints(Path(analysis_dir) / JOINTS_NAME)
    truth = read_joints(Path(truth_csv))
    t = est["t"]
    keep = t >= t[0] + skip_s if len(t) else np.zeros(0, dtype=bool)
    out: dict[str, Any] = {"rows": int(keep.sum()), "skip_s": skip_s, "angles_deg": {}}
    for c in ANGLES:
        want = np.interp(t[keep], truth["t"], truth[c])
        out["angles_deg"][c] = _errors(est[c][keep] - want)
    out["positions_m"] = {}
    for name, cols in POINTS.items():
        got = np.stack([est[c][keep] for c in cols], axis=1)
        want = np.stack([np.interp(t[keep], truth["t"], truth[c]) for c in cols], axis=1)
        out["positions_m"][name] = _errors(np.linalg.norm(got - want, axis=1))
    return out


def _f(x: float | None, digits: int = 2) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def format_tables(res: dict[str, Any]) -> str:
    lines = [
        f"wearable mode: {res['rows']} rows after the first {res['skip_s']:g} s",
        "",
        "| joint angle | RMSE (°) | peak error (°) | rows | empty |",
        "|---|---|---|---|---|",
    ]
    for c, e in res["angles_deg"].items():
        lines.append(f"| {c} | {_f(e['rmse'])} | {_f(e['peak'])} | {e['n']} | {e['missing']} |")
    lines += [
        "",
        "| position | RMSE (cm) | peak error (cm) | rows | empty |",
        "|---|---|---|---|---|",
    ]
    for name, e in res["positions_m"].items():
        rmse = None if e["rmse"] is None else 100 * e["rmse"]
        peak = None if e["peak"] is None else 100 * e["peak"]
        lines.append(f"| {name} | {_f(rmse, 1)} | {_f(peak, 1)} | {e['n']} | {e['missing']} |")
    return "\n".join(lines)
