// A wearable session's live view (contract §8): the joint angles of the last 30 s with their
// confidence (a dashed grey line and the ±2σ band where an angle is not sure: never drawn as
// sure), the newest values, what is wrong, and the ROM test workflow.

import { useEffect, useRef, useState } from "preact/hooks";

import { Alert, KeyFigure } from "./bits";
import { api, errorText } from "../lib/api";
import { ANGLES, ANGLE_LABEL, type Angle } from "../lib/joints";
import type { DeviceLive, LiveClient } from "../lib/live";
import { WINDOW_S } from "../lib/live";
import { Chart, LINE } from "../lib/plots";
import type { RomTest, Session } from "../lib/types";

const DEFAULT_SURE = 7.5; // the service sends its own (status.sure_std_deg)

export const ROM_MOVES: { value: string; label: string }[] = [
  { value: "shoulder_flexion", label: "Maximal shoulder flexion" },
  { value: "shoulder_extension", label: "Maximal shoulder extension" },
  { value: "shoulder_abduction", label: "Maximal shoulder abduction" },
  { value: "shoulder_internal_rotation", label: "Maximal internal rotation" },
  { value: "shoulder_external_rotation", label: "Maximal external rotation" },
  { value: "elbow_flexion", label: "Maximal elbow flexion" },
  { value: "elbow_extension", label: "Maximal elbow extension" },
  { value: "forearm_pronation", label: "Maximal pronation" },
  { value: "forearm_supination", label: "Maximal supination" },
];

function sureStd(dev: DeviceLive): number {
  return dev.status?.sure_std_deg ?? DEFAULT_SURE;
}

export function JointFigures({ dev }: { dev: DeviceLive }) {
  const thr = sureStd(dev);
  return (
    <div class="figures" data-testid="joint-figures">
      {ANGLES.map((a) => {
        const { value, std } = dev.joints.latest(a);
        const sure = value !== null && std !== null && std <= thr;
        const text = value === null ? "–" : `${Math.round(value)}°`;
        const hint = value === null ? "not available" : std === null ? "" : sure ? `± ${std.toFixed(1)}°` : `not sure (± ${std.toFixed(0)}°)`;
        return (
          <div key={a} data-angle={a} data-sure={sure ? "1" : "0"}>
            <KeyFigure label={ANGLE_LABEL[a]} value={sure ? text : <span class="muted">{text}</span>} hint={hint} tone={sure ? undefined : "warn"} />
          </div>
        );
      })}
    </div>
  );
}

export function JointPlots({ client, dev }: { client: LiveClient; dev: DeviceLive }) {
  const refs = useRef<Record<string, HTMLDivElement | null>>({});
  const charts = useRef<Record<string, Chart>>({});
  const seen = useRef(-1);
  useEffect(() => {
    for (const a of ANGLES) {
      const el = refs.current[a];
      if (!el) continue;
      charts.current[a] = new Chart(
        el,
        {
          title: ANGLE_LABEL[a],
          yLabel: "degrees",
          height: 150,
          series: [
            { label: "sure", color: LINE.elbow },
            { label: "not sure", color: LINE.tol, dash: [4, 4] },
            { label: "−2σ", color: "rgba(107,114,128,0.5)", width: 1 },
            { label: "+2σ", color: "rgba(107,114,128,0.5)", width: 1 },
          ],
        },
        [[], [], [], [], []],
      );
    }
    return () => {
      for (const c of Object.values(charts.current)) c.destroy();
      charts.current = {};
    };
  }, []);
  useEffect(
    () =>
      client.subscribe(() => {
        if (dev.version === seen.current) return;
        seen.current = dev.version;
        const J = dev.joints;
        const end = J.t.length ? J.t[J.t.length - 1]! : 0;
        for (const a of ANGLES) {
          const s = J.split(a, sureStd(dev));
          charts.current[a]?.setData([J.t, s.sure, s.unsure, s.lo, s.hi], [end - WINDOW_S, end]);
        }
        client.frameRendered(dev.name);
      }),
    [client, dev],
  );
  return (
    <div class="plots">
      {ANGLES.map((a: Angle) => (
        <figure class="plot" key={a}>
          <figcaption>{ANGLE_LABEL[a]} (°); dashed grey: not sure, thin lines: ±2σ</figcaption>
          <div
            ref={(el) => {
              refs.current[a] = el;
            }}
            class="plot__canvas"
            data-plot={a}
          />
        </figure>
      ))}
    </div>
  );
}

export function RomTestPanel({ dev, session }: { dev: DeviceLive; session: Session }) {
  const [move, setMove] = useState(ROM_MOVES[0]!.value);
  const [busy, setBusy] = useState(false);
  const [error, setError] = useState<string | null>(null);
  const [last, setLast] = useState<RomTest | null>(null);
  const active = dev.status?.rom_active ?? null;
  const done = dev.status?.rom_tests ?? [];
  const act = async (fn: () => Promise<RomTest>) => {
    setBusy(true);
    setError(null);
    try {
      setLast(await fn());
    } catch (e) {
      setError(errorText(e));
    } finally {
      setBusy(false);
    }
  };
  const label = (m: string) => ROM_MOVES.find((x) => x.value === m)?.label ?? m;
  return (
    <section class="card" aria-labelledby="rom-title">
      <h2 id="rom-title">Range-of-motion test</h2>
      <p class="muted">Ask the patient for the movement, start the test, stop it when done: its peak (sure samples only) goes into the session.</p>
      <div class="actions">
        <label class="field field--inline">
          <span>Movement</span>
          <select name="rom-movement" value={move} onChange={(e) => setMove(e.currentTarget.value)} disabled={!!active}>
            {ROM_MOVES.map((m) => (
              <option key={m.value} value={m.value}>
                {m.label}
              </option>
            ))}
          </select>
        </label>
        {active ? (
          <button type="button" class="btn btn--primary" disabled={busy} onClick={() => act(() => api.del<RomTest>(`/api/sessions/${session.id}/rom-test`))}>
            Stop test: {label(active.movement)}
          </button>
        ) : (
          <button type="button" class="btn btn--primary" disabled={busy} onClick={() => act(() => api.post<RomTest>(`/api/sessions/${session.id}/rom-test`, { movement: move }))}>
            Start test
          </button>
        )}
      </div>
      {active && <Alert kind="info">Recording {label(active.movement)}…</Alert>}
      {error && <Alert kind="error">{error}</Alert>}
      {done.length > 0 && (
        <table class="table table--compact" data-testid="rom-results" style={{ width: "100%", tableLayout: "fixed" }}>
          <caption>Tests of this session</caption>
          <thead>
            <tr>
              <th>Movement</th>
              <th>Peak</th>
              <th>Sure samples</th>
            </tr>
          </thead>
          <tbody>
            {done.map((t, i) => (
              <tr key={i}>
                <td>{label(t.movement)}</td>
                <td>{t.peak_deg === null ? "no sure sample" : `${t.peak_deg.toFixed(1)}°`}</td>
                <td>
                  {t.sure_rows} of {t.rows}
                </td>
              </tr>
            ))}
          </tbody>
        </table>
      )}
      {!done.length && last && !active && <p>{label(last.movement)}: {last.peak_deg === null ? "no sure sample" : `${last.peak_deg.toFixed(1)}°`}</p>}
    </section>
  );
}

export function WearableNotes({ dev }: { dev: DeviceLive }) {
  const msgs = dev.status?.messages ?? [];
  const all = (dev.status?.quality as { flagged_rows?: Record<string, number> } | undefined)?.flagged_rows ?? {};
  // camera_used is no fault: the rows the camera corrected
  const flagged = Object.fromEntries(Object.entries(all).filter(([k]) => k !== "camera_used"));
  return (
    <>
      {msgs.map((m) => (
        <Alert kind="warn" key={m}>
          {m}
        </Alert>
      ))}
      {Object.keys(flagged).length > 0 && (
        <p class="muted small" data-testid="flagged">
          Flagged rows: {Object.entries(flagged).map(([k, v]) => `${k.replace(/_/g, " ")} ${v}`).join(" · ")}
        </p>
      )}
    </>
  );
}
