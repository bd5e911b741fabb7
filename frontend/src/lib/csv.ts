// The session's CSV files (contract §6) → columns for plotting, decimated to at most
// `maxPoints` rows (rows without a time are skipped).

/** Rows of `text` as split cells, with a column index by header name. */
function rows(text: string, maxPoints: number): { col: (name: string) => number; cells: string[][] } {
  const lines = text.split("\n");
  const header = (lines[0] ?? "").trim().split(",");
  const it = header.indexOf("t");
  const stride = Math.max(1, Math.ceil((lines.length - 1) / maxPoints));
  const cells: string[][] = [];
  for (let i = 1; i < lines.length; i += stride) {
    const line = lines[i];
    if (!line) continue;
    const c = line.split(",");
    if (num(c[it]) !== null) cells.push(c);
  }
  return { col: (name) => header.indexOf(name), cells };
}

function num(c: string | undefined): number | null {
  if (c === undefined || c === "") return null;
  const v = Number(c);
  return Number.isFinite(v) ? v : null;
}

export interface EstimateColumns {
  t: number[];
  disp: (number | null)[]; // cm
  elbow: (number | null)[];
  state: string[];
}

/** estimates.csv: shoulder displacement, elbow angle and indicator state. */
export function parseEstimates(text: string, maxPoints = 5000): EstimateColumns {
  const { col, cells } = rows(text, maxPoints);
  const [it, id, ie, is] = [col("t"), col("shoulder_displacement_m"), col("elbow_angle_deg"), col("state")];
  return {
    t: cells.map((c) => num(c[it]) as number),
    disp: cells.map((c) => {
      const d = num(c[id]);
      return d === null ? null : d * 100;
    }),
    elbow: cells.map((c) => num(c[ie])),
    state: cells.map((c) => c[is]?.trim() ?? ""),
  };
}

export interface DetailColumns {
  t: number[];
  elevation: (number | null)[]; // ° (0 hanging, 90 horizontal)
  azimuth: (number | null)[]; // °
}

/** details.csv: the upper arm's elevation and azimuth. */
export function parseDetails(text: string, maxPoints = 5000): DetailColumns {
  const { col, cells } = rows(text, maxPoints);
  const [it, iel, iaz] = [col("t"), col("upper_arm_elevation_deg"), col("upper_arm_azimuth_deg")];
  return {
    t: cells.map((c) => num(c[it]) as number),
    elevation: cells.map((c) => num(c[iel])),
    azimuth: cells.map((c) => num(c[iaz])),
  };
}
