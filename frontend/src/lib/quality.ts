// Data-quality counters (estimators.pipeline.Quality) summarised as badges.

import type { Quality } from "./types";

export interface Badge {
  label: string;
  tone: "good" | "warn" | "bad" | "muted";
  title: string;
}

function sum(x: unknown): number {
  if (typeof x === "number" && Number.isFinite(x)) return x;
  if (Array.isArray(x)) return x.length;
  if (x && typeof x === "object") {
    return Object.values(x as Record<string, unknown>).reduce<number>((a, v) => a + sum(v), 0);
  }
  return 0;
}

export function qualityBadges(q: Quality | null | undefined, online: boolean): Badge[] {
  if (!online) return [{ label: "No data", tone: "muted", title: "The device is not sending" }];
  if (!q) return [{ label: "Checking data", tone: "muted", title: "No quality counters yet" }];
  const out: Badge[] = [];
  const rejected = sum(q.rejected);
  const lost = sum(q.seq_lost);
  const gaps = sum(q.robot_gaps) + sum(q.imu_resets);
  if (rejected) {
    const reasons = Object.entries(q.rejected ?? {})
      .map(([k, v]) => `${k}: ${v}`)
      .join(", ");
    out.push({ label: `${rejected} rejected`, tone: "bad", title: `Rejected messages (${reasons})` });
  }
  if (lost) out.push({ label: `${lost} lost`, tone: "warn", title: "Messages lost (sequence gaps)" });
  if (gaps) out.push({ label: `${gaps} gaps`, tone: "warn", title: "Gaps in the sensor streams" });
  if (!out.length) out.push({ label: "Data OK", tone: "good", title: "No rejected, lost or missing data" });
  return out;
}

export function qualityRows(q: Quality | null | undefined): [string, string][] {
  if (!q) return [];
  const rows: [string, string][] = [];
  const named: [keyof Quality, string][] = [
    ["imu_samples", "IMU samples"],
    ["robot_samples", "Robot samples"],
    ["robot_gaps", "Robot gaps"],
    ["robot_bridged_gaps", "Robot gaps bridged"],
    ["imu_bridged_gaps", "IMU gaps bridged"],
    ["imu_resets", "IMU resets"],
    ["rows_without_imu", "Estimates without IMU"],
    ["heading_resets", "Heading resets"],
  ];
  for (const [k, label] of named) {
    const v = q[k];
    if (typeof v === "number") rows.push([label, v.toLocaleString()]);
  }
  const rej = q.rejected ?? {};
  const rejTotal = sum(rej);
  rows.push([
    "Rejected messages",
    rejTotal
      ? `${rejTotal} (${Object.entries(rej)
          .map(([k, v]) => `${k.replaceAll("_", " ")} ${v}`)
          .join(", ")})`
      : "0",
  ]);
  const lost = q.seq_lost ?? {};
  const lostTotal = sum(lost);
  rows.push([
    "Lost messages",
    lostTotal
      ? `${lostTotal} (${Object.entries(lost)
          .map(([k, v]) => `${k} ${v}`)
          .join(", ")})`
      : "0",
  ]);
  return rows;
}
