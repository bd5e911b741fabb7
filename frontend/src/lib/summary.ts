// Figures of a session for trends, from its stored summary or its report (either shape).

import type { Report } from "./types";

export interface SessionFigures {
  cycles: number | null;
  compensatory: number | null;
  compShare: number | null;
  elbowRange: number | null;
  elevRange: number | null;
  azimRange: number | null;
  dispMedian: number | null;
}

function n(x: unknown): number | null {
  return typeof x === "number" && Number.isFinite(x) ? x : null;
}

function obj(x: unknown): Record<string, unknown> | null {
  return x && typeof x === "object" && !Array.isArray(x) ? (x as Record<string, unknown>) : null;
}

function rangeOf(x: unknown): number | null {
  const o = obj(x);
  if (!o) return n(x);
  const r = n(o.range);
  if (r !== null) return r;
  const lo = n(o.p5) ?? n(o.min);
  const hi = n(o.p95) ?? n(o.max);
  return lo !== null && hi !== null ? hi - lo : null;
}

export function figuresOf(src: Record<string, unknown> | Report | null | undefined): SessionFigures | null {
  const r = obj(src);
  if (!r) return null;
  const s = obj(r.summary) ?? r;
  const cycleList = Array.isArray(r.cycles) ? (r.cycles as { compensatory?: boolean }[]) : null;
  const cycles = n(s.cycles) ?? (cycleList ? cycleList.length : null);
  const comp = n(s.compensatory_cycles) ?? (cycleList ? cycleList.filter((c) => c.compensatory).length : null);
  const share = n(s.compensatory_share) ?? (cycles && comp !== null ? comp / cycles : null);
  const disp = obj(r.shoulder_displacement_m);
  const f: SessionFigures = {
    cycles,
    compensatory: comp,
    compShare: share,
    elbowRange: rangeOf(r.elbow_flexion_deg ?? s.elbow_flexion_deg),
    elevRange: rangeOf(r.upper_arm_elevation_deg ?? s.upper_arm_elevation_deg),
    azimRange: rangeOf(r.upper_arm_azimuth_deg ?? s.upper_arm_azimuth_deg),
    dispMedian: disp ? n(disp.median) : n(s.shoulder_displacement_median_m),
  };
  const any = Object.values(f).some((v) => v !== null);
  return any ? f : null;
}

/** Whether the figures suffice for the trends (else the report is fetched). */
export function complete(f: SessionFigures | null): boolean {
  return !!f && f.compShare !== null && f.elbowRange !== null && f.elevRange !== null;
}
