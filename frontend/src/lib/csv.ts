// estimates.csv (contract §6) → columns for plotting, decimated to at most `maxPoints`.

export interface EstimateColumns {
  t: number[];
  disp: (number | null)[]; // cm
  elbow: (number | null)[];
  state: string[];
}

export function parseEstimates(text: string, maxPoints = 5000): EstimateColumns {
  const lines = text.split("\n");
  const header = (lines[0] ?? "").trim().split(",");
  const it = header.indexOf("t");
  const id = header.indexOf("shoulder_displacement_m");
  const ie = header.indexOf("elbow_angle_deg");
  const is = header.indexOf("state");
  const rows = lines.length - 1;
  const stride = Math.max(1, Math.ceil(rows / maxPoints));
  const out: EstimateColumns = { t: [], disp: [], elbow: [], state: [] };
  const val = (c: string | undefined) => {
    if (c === undefined || c === "") return null;
    const v = Number(c);
    return Number.isFinite(v) ? v : null;
  };
  for (let i = 1; i < lines.length; i += stride) {
    const line = lines[i];
    if (!line) continue;
    const c = line.split(",");
    const t = val(c[it]);
    if (t === null) continue;
    out.t.push(t);
    const d = val(c[id]);
    out.disp.push(d === null ? null : d * 100);
    out.elbow.push(val(c[ie]));
    out.state.push(c[is]?.trim() ?? "");
  }
  return out;
}
