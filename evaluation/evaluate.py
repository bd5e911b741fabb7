"""``rehab evaluate``: compare an analysis with simulator ground truth (the paper's tables).

Errors are taken after heading convergence, at each estimate row's time against the truth
interpolated there: shoulder position (3D) and elbow angle, median and 95th percentile, per
phase (proper, compensatory), for the hybrid method and the conventional fixed-shoulder
baseline; a confusion table of cycle verdicts; and the heading convergence time.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

PHASES = {1: "proper", 3: "compensatory"}


def _interp(t: np.ndarray, tt: np.ndarray, x: np.ndarray) -> np.ndarray:
    if x.ndim == 1:
        return np.asarray(np.interp(t, tt, x))
    return np.stack([np.interp(t, tt, x[:, j]) for j in range(x.shape[1])], axis=1)


def stats(e: np.ndarray) -> dict[str, float | int | None]:
    """Median and 95th percentile of the finite values."""
    e = e[np.isfinite(e)]
    if not len(e):
        return {"n": 0, "median": None, "p95": None}
    return {"n": len(e), "median": float(np.median(e)), "p95": float(np.percentile(e, 95))}


def load_truth(path: str | Path) -> dict[str, Any]:
    z = np.load(path, allow_pickle=False)
    return {k: z[k] for k in z.files}


def truth_cycles(truth: dict[str, Any]) -> list[dict[str, Any]]:
    """Truth cycles as dicts with start, end, phase (int) and compensatory (bool)."""
    out = []
    starts = truth["cycles_start"]
    for i in range(len(starts)):
        out.append(
            {
                "start": float(starts[i]),
                "end": float(truth["cycles_end"][i]),
                "phase": int(truth["cycles_phase"][i]),
                "compensatory": bool(truth["cycles_compensatory"][i]),
                "true_outside_fraction": float(truth["cycles_outside_fraction"][i]),
                "true_peak_displacement_m": float(truth["cycles_peak_displacement_m"][i]),
            }
        )
    return out


def evaluate(analysis_dir: str | Path, truth: dict[str, Any]) -> dict[str, Any]:
    from backend.analysis import read_estimates  # the analysis stack: only when evaluating

    d = Path(analysis_dir)
    est = read_estimates(d / "estimates.csv")
    det = read_estimates(d / "details.csv")
    report = json.loads((d / "report.json").read_text())
    t = est["t"]
    tt = truth["t"]
    inside = (t >= tt[0]) & (t <= tt[-1])
    conv = (est["heading_converged"] == 1) & inside
    sh_true = _interp(t, tt, truth["shoulder"])
    ang_true = np.interp(t, tt, truth["elbow_angle_deg"])
    phase = truth["phase"][np.clip(np.searchsorted(tt, t), 0, len(tt) - 1)]
    sh_est = np.stack([est["shoulder_x"], est["shoulder_y"], est["shoulder_z"]], axis=1)
    nominal = np.stack([det["nominal_x"], det["nominal_y"], det["nominal_z"]], axis=1)
    e_sh = np.linalg.norm(sh_est - sh_true, axis=1)
    e_ang = np.abs(est["elbow_angle_deg"] - ang_true)
    e_sh_conv = np.linalg.norm(nominal - sh_true, axis=1)
    e_ang_conv = np.abs(det["conv_elbow_angle_deg"] - ang_true)
    raw = {
        "phase": phase[conv],
        "shoulder_m": e_sh[conv],
        "elbow_deg": e_ang[conv],
        "conv_shoulder_m": e_sh_conv[conv],
        "conv_elbow_deg": e_ang_conv[conv],
    }
    acc: dict[str, Any] = {}
    for code, name in (*PHASES.items(), (0, "all")):
        m = conv & ((phase == code) if code else np.isin(phase, list(PHASES)))
        acc[name] = {
            "shoulder_m": stats(e_sh[m]),
            "elbow_deg": stats(e_ang[m]),
            "conv_shoulder_m": stats(e_sh_conv[m]),
            "conv_elbow_deg": stats(e_ang_conv[m]),
        }
    # cycle verdicts: each truth cycle of a pure phase against the overlapping estimate cycle
    confusion = {
        f"{a}->{b}": 0
        for a in ("proper", "compensatory")
        for b in ("proper", "compensatory", "missed")
    }
    est_cycles = report["cycles"]
    s_est = np.array([c["start"] for c in est_cycles]) if est_cycles else np.zeros(0)
    e_est = np.array([c["end"] for c in est_cycles]) if est_cycles else np.zeros(0)
    conv_t = report["heading"]["converged_t"]
    wrong: list[dict[str, Any]] = []
    for c in truth_cycles(truth):
        if c["phase"] not in PHASES or conv_t is None or c["start"] < conv_t:
            continue
        if c["end"] > t[-1] - (c["end"] - c["start"]):
            continue  # our boundaries sit at another phase: this one ends after the recording
        label = PHASES[c["phase"]]
        overlap = np.minimum(e_est, c["end"]) - np.maximum(s_est, c["start"])
        j = int(np.argmax(overlap)) if len(overlap) else -1
        if j < 0 or overlap[j] < 0.5 * (c["end"] - c["start"]):
            confusion[f"{label}->missed"] += 1
            continue
        verdict = "compensatory" if est_cycles[j]["compensatory"] else "proper"
        confusion[f"{label}->{verdict}"] += 1
        if verdict != label:
            wrong.append({**c, "estimated": est_cycles[j]})
    n_judged = sum(v for k, v in confusion.items() if not k.endswith("missed"))
    n_right = confusion["proper->proper"] + confusion["compensatory->compensatory"]
    moving = np.flatnonzero(truth["phase"] > 0)
    t_motion = float(tt[moving[0]]) if len(moving) else float("nan")
    return {
        "accuracy": acc,
        "cycles": {
            "confusion": confusion,
            "correct": n_right,
            "judged": n_judged,
            "share_correct": (n_right / n_judged) if n_judged else None,
            "misjudged": wrong,
        },
        "heading": {
            "converged_t": conv_t,
            "motion_start_t": t_motion,
            "convergence_s": (conv_t - t_motion) if conv_t is not None else None,
        },
        "upper_arm_length_m": report.get("upper_arm_length_m"),
        "raw": raw,
    }


def _cm(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.1f}"


def _deg(x: float | None) -> str:
    return "—" if x is None else f"{x:.1f}"


def format_tables(res: dict[str, Any]) -> str:
    lines = [
        "| phase | shoulder median / p95 (cm) | conventional (cm) "
        "| elbow median / p95 (°) | conventional (°) |",
        "|---|---|---|---|---|",
    ]
    for name in ("proper", "compensatory", "all"):
        a = res["accuracy"][name]
        lines.append(
            f"| {name} | {_cm(a['shoulder_m']['median'])} / {_cm(a['shoulder_m']['p95'])} "
            f"| {_cm(a['conv_shoulder_m']['median'])} / {_cm(a['conv_shoulder_m']['p95'])} "
            f"| {_deg(a['elbow_deg']['median'])} / {_deg(a['elbow_deg']['p95'])} "
            f"| {_deg(a['conv_elbow_deg']['median'])} / {_deg(a['conv_elbow_deg']['p95'])} |"
        )
    c = res["cycles"]["confusion"]
    lines += [
        "",
        "| true \\ estimated | proper | compensatory | missed |",
        "|---|---|---|---|",
        f"| proper | {c['proper->proper']} | {c['proper->compensatory']} | {c['proper->missed']} |",
        f"| compensatory | {c['compensatory->proper']} | {c['compensatory->compensatory']} "
        f"| {c['compensatory->missed']} |",
        "",
        f"heading converged {res['heading']['convergence_s']} s after the start of motion; "
        f"upper-arm length used {res['upper_arm_length_m']} m",
    ]
    return "\n".join(lines)


def cmd(args: argparse.Namespace) -> int:
    from evaluation import evaluate_wearable as ew

    if ew.is_wearable_analysis(args.analysis):  # contract §8: joints.csv, truth.csv
        wres = ew.evaluate(args.analysis, args.truth)
        print(ew.format_tables(wres))
        if args.json:
            Path(args.json).write_text(json.dumps(wres, indent=1))
        return 0
    res = evaluate(args.analysis, load_truth(args.truth))
    print(format_tables(res))
    if args.json:
        res.pop("raw")
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0


def add_parser(sub: Any) -> None:
    p = sub.add_parser("evaluate", help="compare an analysis with simulator ground truth")
    p.add_argument("analysis", help="directory written by `rehab analyze`")
    p.add_argument(
        "--truth",
        required=True,
        help="truth.npz written by `rehab simulate` (wearable mode: its truth.csv)",
    )
    p.add_argument("--json", help="also write the figures as JSON")
    p.set_defaults(func=cmd)
