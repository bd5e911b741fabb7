// Number and date formatting for people (units always shown).

export function cm(m: number | null | undefined, digits = 1): string {
  return m === null || m === undefined || !Number.isFinite(m) ? "–" : `${(m * 100).toFixed(digits)} cm`;
}

export function deg(x: number | null | undefined, digits = 0): string {
  return x === null || x === undefined || !Number.isFinite(x) ? "–" : `${x.toFixed(digits)}°`;
}

export function pct(f: number | null | undefined, digits = 0): string {
  return f === null || f === undefined || !Number.isFinite(f) ? "–" : `${(f * 100).toFixed(digits)} %`;
}

export function num(x: number | null | undefined, digits = 1, unit = ""): string {
  if (x === null || x === undefined || !Number.isFinite(x)) return "–";
  return unit ? `${x.toFixed(digits)} ${unit}` : x.toFixed(digits);
}

export function seconds(s: number | null | undefined): string {
  if (s === null || s === undefined || !Number.isFinite(s)) return "–";
  if (s < 60) return `${s.toFixed(1)} s`;
  const m = Math.floor(s / 60);
  return `${m} min ${Math.round(s - m * 60)} s`;
}

export function dateTime(iso: string | null | undefined): string {
  if (!iso) return "–";
  const d = new Date(iso);
  return d.toLocaleString(undefined, {
    year: "numeric",
    month: "short",
    day: "numeric",
    hour: "2-digit",
    minute: "2-digit",
  });
}

export function shortDate(iso: string | null | undefined): string {
  if (!iso) return "–";
  return new Date(iso).toLocaleDateString(undefined, { month: "short", day: "numeric" });
}

export function duration(startIso: string, endIso: string | null, now = Date.now()): string {
  const a = new Date(startIso).getTime();
  const b = endIso ? new Date(endIso).getTime() : now;
  const s = Math.max(0, Math.round((b - a) / 1000));
  const m = Math.floor(s / 60);
  return m ? `${m} min ${String(s % 60).padStart(2, "0")} s` : `${s} s`;
}

/** The tolerated time outside before the warning; null: adaptive (a share of the last cycle). */
export function warningAfter(s: number | null | undefined, maxOutsideFraction: number | null | undefined): string {
  if (s === null) {
    const share = maxOutsideFraction ?? 0.2;
    return `warning after ${Math.round(share * 100)} % of the last cycle (adaptive)`;
  }
  return s === undefined || !Number.isFinite(s) ? "–" : `warning after ${num(s, 1, "s")}`;
}
