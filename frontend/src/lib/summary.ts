// Figures of a session for a patient's history and trends, from the summary the sessions
// list carries (GET /api/sessions): no report is fetched (a report is an audited export).

import type { SessionSummary } from "./types";

export interface SessionFigures {
  cycles: number | null;
  compensatory: number | null;
  compShare: number | null;
  elbowRange: number | null;
  elevRange: number | null;
  azimRange: number | null;
  dispMedian: number | null;
  dispP95: number | null;
  /** ISB shoulder elevation's active range (anatomical ROM) */
  isbElevRange: number | null;
  sparcMedian: number | null;
  straightnessMedian: number | null;
  unitsMedian: number | null;
}

function n(x: unknown): number | null {
  return typeof x === "number" && Number.isFinite(x) ? x : null;
}

function obj(x: unknown): Record<string, unknown> | null {
  return x && typeof x === "object" && !Array.isArray(x) ? (x as Record<string, unknown>) : null;
}

/** The robust range (p5..p95) of a range of motion, else max − min. */
function rangeOf(x: unknown): number | null {
  const o = obj(x);
  if (!o) return null;
  const r = n(o.range);
  if (r !== null) return r;
  const lo = n(o.p5) ?? n(o.min);
  const hi = n(o.p95) ?? n(o.max);
  return lo !== null && hi !== null ? hi - lo : null;
}

/** The figures of a summary, or null when it has none (a session without data). */
export function figuresOf(s: SessionSummary | null | undefined): SessionFigures | null {
  if (!s) return null;
  const cycles = n(s.cycles);
  const comp = n(s.compensatory_cycles);
  const disp = obj(s.shoulder_displacement_m);
  const f: SessionFigures = {
    cycles,
    compensatory: comp,
    compShare: n(s.compensatory_share) ?? (cycles && comp !== null ? comp / cycles : null),
    // a wearable session has the elbow only in its anatomical ROM (the same angle)
    elbowRange: rangeOf(s.elbow_flexion_deg) ?? rangeOf(obj(s.anatomical_rom_deg)?.elbow_flexion_deg),
    elevRange: rangeOf(s.upper_arm_elevation_deg),
    azimRange: rangeOf(s.upper_arm_azimuth_deg),
    dispMedian: disp ? n(disp.median) : null,
    dispP95: disp ? n(disp.p95) : null,
    isbElevRange: rangeOf(obj(s.anatomical_rom_deg)?.shoulder_elevation_deg),
    sparcMedian: n(obj(s.movement_quality_median)?.sparc),
    straightnessMedian: n(obj(s.movement_quality_median)?.straightness_ratio),
    unitsMedian: n(obj(s.movement_quality_median)?.movement_units),
  };
  return Object.values(f).some((v) => v !== null) ? f : null;
}
