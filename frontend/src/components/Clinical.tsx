// The report's clinical sections: range of motion in anatomical terms (ISB shoulder angles,
// elbow flexion), movement quality per cycle (table, plot, session medians) and the wrist
// path seen from above per cycle, coloured by verdict.

import { useMemo } from "preact/hooks";
import type { AlignedData } from "uplot";

import { deg, num } from "../lib/format";
import { LINE, type ChartSpec } from "../lib/plots";
import { QUALITY_FIELDS, type AnatomicalRom, type MovementQuality, type QualityCycle, type QualityField, type Range } from "../lib/types";
import { StaticChart } from "./StaticChart";

export const ANGLE_NAMES: Record<string, string> = {
  shoulder_plane_of_elevation_deg: "Shoulder plane of elevation",
  shoulder_elevation_deg: "Shoulder elevation",
  shoulder_axial_rotation_deg: "Shoulder axial rotation",
  elbow_flexion_deg: "Elbow flexion",
  // the wearable mode's own joint angles (contract §8), beside the ISB ones
  shoulder_flexion_deg: "Shoulder flexion (model)",
  shoulder_abduction_deg: "Shoulder abduction (model)",
  shoulder_rotation_deg: "Shoulder internal rotation (model)",
  forearm_pronation_deg: "Forearm pronation (model)",
};

/** What a report's rows are: a robot session's judged cycles or a wearable one's movements. */
export type Unit = "cycle" | "movement";

/** label, unit, digits */
export const QUALITY_NAMES: Record<QualityField, [string, string, number]> = {
  movement_time_s: ["Movement time", "s", 1],
  path_length_m: ["Path length", "m", 2],
  straightness_ratio: ["Straightness", "", 2],
  mean_speed_m_s: ["Mean speed", "m/s", 2],
  peak_speed_m_s: ["Peak speed", "m/s", 2],
  movement_units: ["Movement units", "", 0],
  sparc: ["SPARC", "", 2],
  ldlj: ["LDLJ", "", 1],
};

export function RomTable({ rom, caption }: { rom: Record<string, Range>; caption: string }) {
  return (
    <div class="table-wrap">
      <table class="table" data-table="rom">
        <caption class="sr-only">{caption}</caption>
        <thead>
          <tr>
            <th scope="col">Angle</th>
            <th scope="col">min</th>
            <th scope="col">max</th>
            <th scope="col">p5</th>
            <th scope="col">p95</th>
            <th scope="col">Active range (p5–p95)</th>
          </tr>
        </thead>
        <tbody>
          {Object.entries(rom).map(([name, r]) => (
            <tr key={name}>
              <th scope="row">{ANGLE_NAMES[name] ?? name}</th>
              <td>{deg(r.min)}</td>
              <td>{deg(r.max)}</td>
              <td>{deg(r.p5)}</td>
              <td>{deg(r.p95)}</td>
              <td>
                <strong>{deg(r.range)}</strong>
              </td>
            </tr>
          ))}
        </tbody>
      </table>
    </div>
  );
}

export function AnatomicalRomSection({ rom, t0, unit = "cycle" }: { rom: AnatomicalRom; t0: number; unit?: Unit }) {
  const names = Object.keys(rom.session);
  return (
    <section class="card" aria-labelledby="rom-title">
      <h2 id="rom-title">Range of motion, anatomical (ISB)</h2>
      <RomTable rom={rom.session} caption="Range of motion of the session, degrees" />
      {rom.cycles.length > 0 && (
        <details>
          <summary>
            Per {unit} ({rom.cycles.length} {unit}s): p5 – p95 and active range
          </summary>
          <div class="table-wrap">
            <table class="table" data-table="rom-cycles">
              <caption class="sr-only">Range of motion per {unit}, degrees</caption>
              <thead>
                <tr>
                  <th scope="col">#</th>
                  <th scope="col">Start</th>
                  {names.map((n) => (
                    <th scope="col" key={n}>
                      {ANGLE_NAMES[n] ?? n}
                    </th>
                  ))}
                </tr>
              </thead>
              <tbody>
                {rom.cycles.map((c, i) => (
                  <tr key={i}>
                    <td>{i + 1}</td>
                    <td>{num(c.start - t0, 1, "s")}</td>
                    {names.map((n) => {
                      const r = c.angles[n];
                      return <td key={n}>{r && r.range != null ? `${deg(r.p5)} – ${deg(r.p95)} (${deg(r.range)})` : "–"}</td>;
                    })}
                  </tr>
                ))}
              </tbody>
            </table>
          </div>
        </details>
      )}
      <p class="muted small" data-note="frame">
        {rom.note} {rom.convention}
      </p>
    </section>
  );
}

const OK = LINE.ok;
const COMP = "#D55E00"; // Okabe–Ito vermillion
const NONE = LINE.disp; // a wearable session's movements: no verdict

function verdictOf(c: QualityCycle): "compensatory" | "proper" | "none" {
  return c.compensatory == null ? "none" : c.compensatory ? "compensatory" : "proper";
}

/** Every cycle's wrist path from above (x right, y forward), one colour per verdict. */
export function WristPaths({ quality, unit = "cycle" }: { quality: MovementQuality; unit?: Unit }) {
  const paths = quality.cycles.filter((c) => c.path_xy.length > 1);
  const box = useMemo(() => {
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (const c of paths)
      for (const [x, y] of c.path_xy) {
        x0 = Math.min(x0, x);
        x1 = Math.max(x1, x);
        y0 = Math.min(y0, y);
        y1 = Math.max(y1, y);
      }
    const pad = Math.max(x1 - x0, y1 - y0, 0.05) * 0.08;
    return { x0: x0 - pad, y0: y0 - pad, w: x1 - x0 + 2 * pad, h: y1 - y0 + 2 * pad };
  }, [quality]);
  if (!paths.length) return <p class="muted">No wrist path.</p>;
  const nComp = paths.filter((c) => c.compensatory).length;
  const judged = paths.some((c) => c.compensatory != null);
  // y forward is up on screen: flip y
  const pts = (xy: [number, number][]) => xy.map(([x, y]) => `${(x - box.x0).toFixed(4)},${(box.h - (y - box.y0)).toFixed(4)}`).join(" ");
  return (
    <figure class="plot" data-plot="wrist-paths">
      <figcaption>
        Wrist path from above, per {unit} (forward is up):{" "}
        {judged ? (
          <>
            <span style={{ color: OK }}>━ proper ({paths.length - nComp})</span> <span style={{ color: COMP }}>┅ compensatory ({nComp})</span>
          </>
        ) : (
          <span style={{ color: NONE }}>━ {paths.length} {unit}s, no verdict</span>
        )}{" "}
        · {(box.w * 100).toFixed(0)} × {(box.h * 100).toFixed(0)} cm
      </figcaption>
      <svg
        viewBox={`0 0 ${box.w} ${box.h}`}
        role="img"
        aria-label={`Wrist paths of ${paths.length} ${unit}s seen from above${judged ? `, ${nComp} compensatory` : ""}`}
        style={{ width: "100%", maxWidth: "420px", maxHeight: "320px", background: "#fafafa" }}
      >
        {paths.map((c, i) => (
          <polyline
            key={i}
            points={pts(c.path_xy)}
            fill="none"
            stroke={{ compensatory: COMP, proper: OK, none: NONE }[verdictOf(c)]}
            stroke-width={box.w / 250}
            stroke-dasharray={c.compensatory ? `${box.w / 80} ${box.w / 160}` : undefined}
            opacity={0.8}
            data-verdict={verdictOf(c)}
          />
        ))}
      </svg>
    </figure>
  );
}

export function MovementQualitySection({ quality, t0, unit = "cycle" }: { quality: MovementQuality; t0: number; unit?: Unit }) {
  const labels = quality.cycles.map((_, i) => String(i + 1));
  const spec: ChartSpec = useMemo(
    () => ({
      title: `Smoothness per ${unit}`,
      yLabel: "SPARC",
      x: "sessions",
      xLabels: () => labels,
      height: 200,
      series: [{ label: "SPARC (closer to 0 is smoother)", color: LINE.disp, points: true, width: 1.5 }],
    }),
    [labels.join("|"), unit],
  );
  const data = useMemo(() => [quality.cycles.map((_, i) => i), quality.cycles.map((c) => c.sparc)] as AlignedData, [quality]);
  const med = quality.session_median;
  return (
    <section class="card" aria-labelledby="mq-title">
      <h2 id="mq-title">Movement quality</h2>
      <div class="figures figures--row" aria-label="Session medians">
        {(["sparc", "straightness_ratio", "movement_units", "peak_speed_m_s"] as const).map((k) => (
          <div class="figure" key={k}>
            <div class="figure__label">{QUALITY_NAMES[k][0]}, median</div>
            <div class="figure__value" data-median={k}>
              {num(med[k], QUALITY_NAMES[k][2], QUALITY_NAMES[k][1])}
            </div>
          </div>
        ))}
      </div>
      <div class="plots">
        <WristPaths quality={quality} unit={unit} />
        {quality.cycles.length > 0 && <StaticChart name="report-sparc" caption={`Smoothness (SPARC) per ${unit}`} spec={spec} data={data} />}
      </div>
      <div class="table-wrap">
        <table class="table" data-table="movement-quality">
          <caption class="sr-only">Movement quality per {unit}</caption>
          <thead>
            <tr>
              <th scope="col">#</th>
              <th scope="col">Start</th>
              <th scope="col">Verdict</th>
              {QUALITY_FIELDS.map((k) => (
                <th scope="col" key={k}>
                  {QUALITY_NAMES[k][0]}
                  {QUALITY_NAMES[k][1] ? ` (${QUALITY_NAMES[k][1]})` : ""}
                </th>
              ))}
            </tr>
          </thead>
          <tbody>
            {quality.cycles.map((c, i) => (
              <tr key={i}>
                <td>{i + 1}</td>
                <td>{num(c.start - t0, 1, "s")}</td>
                <td>
                  {c.compensatory == null ? (
                    <span class="muted">no verdict</span>
                  ) : c.compensatory ? (
                    <span class="verdict verdict--comp">✗ Compensatory</span>
                  ) : (
                    <span class="verdict verdict--ok">✓ Proper</span>
                  )}
                </td>
                {QUALITY_FIELDS.map((k) => (
                  <td key={k}>{num(c[k], QUALITY_NAMES[k][2])}</td>
                ))}
              </tr>
            ))}
            <tr class="table__total">
              <th scope="row" colSpan={3}>
                Session median
              </th>
              {QUALITY_FIELDS.map((k) => (
                <td key={k}>
                  <strong>{num(med[k], QUALITY_NAMES[k][2])}</strong>
                </td>
              ))}
            </tr>
          </tbody>
        </table>
      </div>
      <p class="muted small">{quality.note}</p>
    </section>
  );
}
