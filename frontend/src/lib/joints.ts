// A wearable device's joint angles (contract §8) and their confidence: the last seconds of
// each angle and its standard deviation, for the live plots. An angle whose standard deviation
// exceeds the service's threshold (status.sure_std_deg) is never drawn as sure.

import type { Num } from "./types";

export const ANGLES = [
  "shoulder_flexion_deg",
  "shoulder_abduction_deg",
  "shoulder_rotation_deg",
  "elbow_flexion_deg",
  "forearm_pronation_deg",
] as const;
export type Angle = (typeof ANGLES)[number];

export const ANGLE_LABEL: Record<Angle, string> = {
  shoulder_flexion_deg: "Shoulder flexion",
  shoulder_abduction_deg: "Shoulder abduction",
  shoulder_rotation_deg: "Shoulder internal rotation",
  elbow_flexion_deg: "Elbow flexion",
  forearm_pronation_deg: "Forearm pronation",
};

export const stdOf = (a: Angle): string => `${a.slice(0, -4)}_std_deg`;

export class JointSeries {
  t: number[] = [];
  angle: Record<string, Num[]> = {};
  std: Record<string, Num[]> = {};

  constructor() {
    for (const a of ANGLES) {
      this.angle[a] = [];
      this.std[a] = [];
    }
  }

  apply(rows: Record<string, Num[]>, windowS: number): void {
    const t = rows.t ?? [];
    const last = this.t.at(-1);
    if (last !== undefined && t.length && t[0]! < last - 1) {
      Object.assign(this, new JointSeries()); // the device's clock went back: afresh
    }
    for (let i = 0; i < t.length; i++) {
      const ti = t[i];
      if (ti === null || ti === undefined) continue;
      if (this.t.length && ti <= this.t[this.t.length - 1]!) continue;
      this.t.push(ti);
      for (const a of ANGLES) {
        this.angle[a]!.push(rows[a]?.[i] ?? null);
        this.std[a]!.push(rows[stdOf(a)]?.[i] ?? null);
      }
    }
    const end = this.t.at(-1);
    if (end !== undefined && this.t.length > 64 && this.t[0]! < end - windowS * 1.25) {
      let k = 0;
      while (k < this.t.length && this.t[k]! < end - windowS) k++;
      this.t.splice(0, k);
      for (const a of ANGLES) {
        this.angle[a]!.splice(0, k);
        this.std[a]!.splice(0, k);
      }
    }
  }

  latest(a: Angle): { value: Num; std: Num } {
    const n = this.t.length - 1;
    return { value: n >= 0 ? this.angle[a]![n]! : null, std: n >= 0 ? this.std[a]![n]! : null };
  }

  /** The angle split in two series: sure (std ≤ threshold) and not sure (the rest). */
  split(a: Angle, sureStd: number): { sure: Num[]; unsure: Num[]; lo: Num[]; hi: Num[] } {
    const v = this.angle[a]!;
    const s = this.std[a]!;
    const sure: Num[] = [];
    const unsure: Num[] = [];
    const lo: Num[] = [];
    const hi: Num[] = [];
    for (let i = 0; i < v.length; i++) {
      const x = v[i] ?? null;
      const sd = s[i] ?? null;
      const ok = x !== null && sd !== null && sd <= sureStd;
      sure.push(ok ? x : null);
      unsure.push(x !== null && !ok ? x : null);
      lo.push(x !== null && sd !== null ? x - 2 * sd : null);
      hi.push(x !== null && sd !== null ? x + 2 * sd : null);
    }
    return { sure, unsure, lo, hi };
  }
}
