import { useEffect, useMemo, useState } from "preact/hooks";
import type { AlignedData } from "uplot";

import { Alert, KeyFigure } from "../components/bits";
import { PatientForm } from "../components/PatientForm";
import { StaticChart } from "../components/StaticChart";
import { api, errorText } from "../lib/api";
import { cm, dateTime, deg, duration, num, pct, shortDate, warningAfter } from "../lib/format";
import { LINE, type ChartSpec } from "../lib/plots";
import { figuresOf, type SessionFigures } from "../lib/summary";
import type { Device, Patient, Session } from "../lib/types";

const STATUS_TEXT: Record<Session["status"], string> = {
  active: "● Running",
  stopped: "Finished",
  interrupted: "⚠ Interrupted",
};

const COMPARE_ROWS: [string, keyof SessionFigures, (v: number | null | undefined) => string][] = [
  ["Cycles", "cycles", (v) => (v == null ? "–" : String(v))],
  ["Compensatory cycles", "compShare", (v) => pct(v)],
  ["Shoulder displacement, median", "dispMedian", (v) => cm(v)],
  ["Elbow flexion, active range", "elbowRange", (v) => deg(v)],
  ["Shoulder elevation (ISB), active range", "isbElevRange", (v) => deg(v)],
  ["Upper-arm elevation, range", "elevRange", (v) => deg(v)],
  ["Smoothness (SPARC), median", "sparcMedian", (v) => num(v, 2)],
  ["Straightness, median", "straightnessMedian", (v) => num(v, 2)],
  ["Movement units, median", "unitsMedian", (v) => num(v, 0)],
];

/** Two finished sessions side by side (default: the last two). */
function Compare({ sessions, figures }: { sessions: Session[]; figures: Map<number, SessionFigures> }) {
  const done = sessions.filter((s) => figures.has(s.id));
  const [a, setA] = useState<number | null>(null);
  const [b, setB] = useState<number | null>(null);
  if (done.length < 2) return <p class="empty">Comparing needs two finished sessions.</p>;
  const left = done.find((s) => s.id === a) ?? done[1]!;
  const right = done.find((s) => s.id === b) ?? done[0]!;
  const pick = (value: number, set: (n: number) => void, label: string) => (
    <label class="field field--inline">
      <span>{label}</span>
      <select value={value} onChange={(e) => set(Number(e.currentTarget.value))} data-compare={label}>
        {done.map((s) => (
          <option key={s.id} value={s.id}>
            {dateTime(s.started_at)} · {s.device}
          </option>
        ))}
      </select>
    </label>
  );
  const fl = figures.get(left.id)!;
  const fr = figures.get(right.id)!;
  return (
    <div>
      <div class="session-bar__row">
        {pick(left.id, setA, "Session A")}
        {pick(right.id, setB, "Session B")}
      </div>
      <div class="table-wrap">
        <table class="table" data-table="compare">
          <caption class="sr-only">Two sessions side by side</caption>
          <thead>
            <tr>
              <th scope="col">Figure</th>
              <th scope="col">
                A · <a href={`/sessions/${left.id}`}>{shortDate(left.started_at)}</a>
              </th>
              <th scope="col">
                B · <a href={`/sessions/${right.id}`}>{shortDate(right.started_at)}</a>
              </th>
            </tr>
          </thead>
          <tbody>
            {COMPARE_ROWS.map(([label, key, fmt]) => (
              <tr key={key}>
                <th scope="row">{label}</th>
                <td>{fmt(fl[key])}</td>
                <td>{fmt(fr[key])}</td>
              </tr>
            ))}
          </tbody>
        </table>
      </div>
    </div>
  );
}

function Trends({ sessions, figures }: { sessions: Session[]; figures: Map<number, SessionFigures> }) {
  const done = sessions.filter((s) => figures.has(s.id)).reverse(); // oldest first
  const labels = done.map((s) => shortDate(s.started_at));
  const xs = done.map((_, i) => i);
  const col = (k: keyof SessionFigures, scale = 1) =>
    done.map((s) => {
      const v = figures.get(s.id)?.[k];
      return v === null || v === undefined ? null : v * scale;
    });
  const specs = useMemo(() => {
    const base = { x: "sessions" as const, xLabels: () => labels, height: 200 };
    const share: ChartSpec = { ...base, title: "Compensatory cycles", yLabel: "%", yRange: [0, 100], series: [{ label: "Compensatory cycles", color: LINE.comp, points: true }] };
    const elbow: ChartSpec = { ...base, title: "Elbow range", yLabel: "degrees", yMin: 0, series: [{ label: "Elbow flexion range", color: LINE.elbow, points: true }] };
    const shoulder: ChartSpec = {
      ...base,
      title: "Shoulder range",
      yLabel: "degrees",
      yMin: 0,
      series: [
        { label: "Upper-arm elevation range", color: LINE.elev, points: true },
        { label: "Horizontal (azimuth) range", color: LINE.azim, points: true, dash: [6, 3] },
      ],
    };
    const smooth: ChartSpec = { ...base, title: "Smoothness", yLabel: "SPARC", series: [{ label: "SPARC, session median", color: LINE.disp, points: true }] };
    const isb: ChartSpec = { ...base, title: "Shoulder elevation (ISB)", yLabel: "degrees", yMin: 0, series: [{ label: "Shoulder elevation active range", color: LINE.elev, points: true }] };
    return { share, elbow, shoulder, smooth, isb };
  }, [labels.join("|")]);
  const data = useMemo(
    () => ({
      share: [xs, col("compShare", 100)] as AlignedData,
      elbow: [xs, col("elbowRange")] as AlignedData,
      shoulder: [xs, col("elevRange"), col("azimRange")] as AlignedData,
      smooth: [xs, col("sparcMedian")] as AlignedData,
      isb: [xs, col("isbElevRange")] as AlignedData,
    }),
    [done.length, figures],
  );
  if (done.length === 0) {
    return <p class="empty">Trends appear after the first finished session.</p>;
  }
  return (
    <div class="plots plots--3">
      <StaticChart name="trend-compensatory" caption="Compensatory cycles (% of the cycles)" spec={specs.share} data={data.share} />
      <StaticChart name="trend-elbow" caption="Elbow range of motion (°)" spec={specs.elbow} data={data.elbow} />
      <StaticChart name="trend-shoulder" caption="Shoulder range of motion (°)" spec={specs.shoulder} data={data.shoulder} />
      <StaticChart name="trend-isb" caption="Shoulder elevation, anatomical active range (°)" spec={specs.isb} data={data.isb} />
      <StaticChart name="trend-sparc" caption="Smoothness, SPARC session median (closer to 0 is smoother)" spec={specs.smooth} data={data.smooth} />
    </div>
  );
}

export function PatientPage({ id }: { id: number }) {
  const [patient, setPatient] = useState<Patient | null>(null);
  const [sessions, setSessions] = useState<Session[] | null>(null);
  const [devices, setDevices] = useState<Device[]>([]);
  const [device, setDevice] = useState("");
  const [editing, setEditing] = useState(false);
  const [error, setError] = useState<string | null>(null);

  useEffect(() => {
    let alive = true;
    api.get<Patient>(`/api/patients/${id}`).then((p) => alive && setPatient(p)).catch((e) => setError(errorText(e)));
    api
      .get<Device[]>("/api/devices")
      .then((d) => {
        if (!alive) return;
        setDevices(d);
        const free = d.find((x) => x.status === "online" && !x.active_session_id);
        if (free) setDevice(free.name);
      })
      .catch(() => undefined);
    // Each finished session's summary carries its figures (range of motion included):
    // the history reads no report.
    api
      .get<Session[]>(`/api/sessions?patient_id=${id}&limit=200`)
      .then((list) => alive && setSessions(list))
      .catch((e) => setError(errorText(e)));
    return () => {
      alive = false;
    };
  }, [id]);

  const figures = useMemo(() => {
    const figs = new Map<number, SessionFigures>();
    for (const s of sessions ?? []) {
      const f = s.status === "active" ? null : figuresOf(s.summary);
      if (f) figs.set(s.id, f);
    }
    return figs;
  }, [sessions]);

  if (error) return <Alert kind="error">{error}</Alert>;
  if (!patient) return <p role="status">Loading…</p>;

  const finished = (sessions ?? []).filter((s) => figures.has(s.id));
  const last = finished[0] ? figures.get(finished[0].id) : undefined;
  const running = (sessions ?? []).find((s) => s.status === "active");

  return (
    <section class="page" aria-labelledby="patient-title">
      <div class="page__head">
        <h1 id="patient-title">Patient {patient.code}</h1>
        <span class="muted">
          {patient.affected_side === "left" ? "Left" : "Right"} arm affected · tolerance {Math.round(patient.tolerance_m * 100)} cm · {warningAfter(patient.warning_after_s, patient.max_outside_fraction)}
        </span>
        <button type="button" class="btn btn--ghost" aria-expanded={editing} onClick={() => setEditing(!editing)}>
          {editing ? "Close" : "Edit"}
        </button>
      </div>
      {editing && (
        <section class="card" aria-label="Edit patient">
          <PatientForm
            patient={patient}
            onSaved={(p) => {
              setPatient(p);
              setEditing(false);
            }}
            onCancel={() => setEditing(false)}
          />
        </section>
      )}

      <section class="card session-bar" aria-labelledby="start-title">
        <h2 id="start-title">Therapy session</h2>
        {running ? (
          <p>
            A session is running on <a href={`/devices/${running.device}`}>{running.device}</a>.
          </p>
        ) : (
          <div class="session-bar__row">
            <label class="field field--inline">
              <span>Device</span>
              <select value={device} onChange={(e) => setDevice(e.currentTarget.value)}>
                <option value="">Choose a device…</option>
                {devices.map((d) => (
                  <option key={d.name} value={d.name} disabled={!!d.active_session_id}>
                    {d.name} · {d.status === "online" ? "online" : "offline"}
                    {d.active_session_id ? " · busy" : ""}
                  </option>
                ))}
              </select>
            </label>
            <a class={`btn btn--primary${device ? "" : " btn--disabled"}`} aria-disabled={!device} href={device ? `/devices/${device}?patient=${patient.id}` : undefined}>
              Go to the device
            </a>
          </div>
        )}
      </section>

      {last && (
        <div class="figures figures--row" aria-label="Last session">
          <KeyFigure label="Compensatory cycles, last session" value={pct(last.compShare)} hint={`${last.compensatory ?? "–"} of ${last.cycles ?? "–"} cycles`} />
          <KeyFigure label="Elbow range, last session" value={deg(last.elbowRange)} />
          <KeyFigure label="Shoulder elevation range, last session" value={deg(last.elevRange)} />
        </div>
      )}

      <section class="card" aria-labelledby="trends-title">
        <h2 id="trends-title">Trends across sessions</h2>
        {sessions === null ? <p role="status">Loading…</p> : <Trends sessions={sessions} figures={figures} />}
      </section>

      <section class="card" aria-labelledby="compare-title">
        <h2 id="compare-title">Compare two sessions</h2>
        {sessions === null ? <p role="status">Loading…</p> : <Compare sessions={sessions} figures={figures} />}
      </section>

      <section class="card" aria-labelledby="sessions-title">
        <h2 id="sessions-title">Sessions</h2>
        {sessions && sessions.length === 0 && <p class="empty">No sessions yet.</p>}
        {sessions && sessions.length > 0 && (
          <div class="table-wrap">
            <table class="table">
              <caption class="sr-only">Sessions of patient {patient.code}, newest first</caption>
              <thead>
                <tr>
                  <th scope="col">Started</th>
                  <th scope="col">Duration</th>
                  <th scope="col">Device</th>
                  <th scope="col">Status</th>
                  <th scope="col">Cycles</th>
                  <th scope="col">Compensatory</th>
                  <th scope="col">Elbow range</th>
                  <th scope="col">Elevation range</th>
                  <th scope="col">Azimuth range</th>
                  <th scope="col">Shoulder displacement (median / p95)</th>
                  <th scope="col">
                    <span class="sr-only">Report</span>
                  </th>
                </tr>
              </thead>
              <tbody>
                {sessions.map((s) => {
                  const f = figures.get(s.id);
                  return (
                    <tr key={s.id}>
                      <td>{dateTime(s.started_at)}</td>
                      <td>{duration(s.started_at, s.stopped_at)}</td>
                      <td>{s.device}</td>
                      <td>{STATUS_TEXT[s.status]}</td>
                      <td>{f?.cycles ?? "–"}</td>
                      <td>{pct(f?.compShare)}</td>
                      <td>{deg(f?.elbowRange)}</td>
                      <td>{deg(f?.elevRange)}</td>
                      <td>{deg(f?.azimRange)}</td>
                      <td>
                        {cm(f?.dispMedian)} / {cm(f?.dispP95)}
                      </td>
                      <td>
                        {s.status === "active" ? (
                          <a href={`/devices/${s.device}`}>Live view</a>
                        ) : (
                          <a href={`/sessions/${s.id}`}>Report</a>
                        )}
                      </td>
                    </tr>
                  );
                })}
              </tbody>
            </table>
          </div>
        )}
      </section>
    </section>
  );
}
