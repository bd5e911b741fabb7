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
  for (let i = 1; i < lines.length; i += stride) {
    const line = lines[i];
    if (!line) continue;
    const c = line.split(",");
    const t = num(c[it]);
    if (t === null) continue;
    out.t.push(t);
    const d = num(c[id]);
    out.disp.push(d === null ? null : d * 100);
    out.elbow.push(num(c[ie]));
    out.state.push(c[is]?.trim() ?? "");
  }
  return out;
}

// details.csv (contract §6): the upper arm's elevation and azimuth over the session.
export interface DetailColumns {
  t: number[];
  elevation: (number | null)[]; // ° (0 hanging, 90 horizontal)
  azimuth: (number | null)[]; // °
}

export function parseDetails(text: string, maxPoints = 5000): DetailColumns {
  const lines = text.split("\n");
  const header = (lines[0] ?? "").trim().split(",");
  const it = header.indexOf("t");
  const iel = header.indexOf("upper_arm_elevation_deg");
  const iaz = header.indexOf("upper_arm_azimuth_deg");
  const stride = Math.max(1, Math.ceil((lines.length - 1) / maxPoints));
  const out: DetailColumns = { t: [], elevation: [], azimuth: [] };
  for (let i = 1; i < lines.length; i += stride) {
    const line = lines[i];
    if (!line) continue;
    const c = line.split(",");
    const t = num(c[it]);
    if (t === null) continue;
    out.t.push(t);
    out.elevation.push(num(c[iel]));
    out.azimuth.push(num(c[iaz]));
  }
  return out;
}

function num(c: string | undefined): number | null {
  if (c === undefined || c === "") return null;
  const v = Number(c);
  return Number.isFinite(v) ? v : null;
}
