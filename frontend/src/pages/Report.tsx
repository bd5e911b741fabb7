import { useEffect, useMemo, useState } from "preact/hooks";
import type { AlignedData } from "uplot";

import { Alert, CycleCounts, CycleTable, KeyFigure } from "../components/bits";
import { AnatomicalRomSection, MovementQualitySection } from "../components/Clinical";
import { StaticChart } from "../components/StaticChart";
import { api, ApiError, errorText, getText } from "../lib/api";
import { parseDetails, parseEstimates, type DetailColumns, type EstimateColumns } from "../lib/csv";
import { cm, dateTime, deg, duration, num, pct, seconds } from "../lib/format";
import { LINE, type ChartSpec } from "../lib/plots";
import { qualityRows } from "../lib/quality";
import { unwrapReport, type Cycle, type Report, type ReportOut, type Session } from "../lib/types";

export function ReportPage({ id }: { id: number }) {
  const [session, setSession] = useState<Session | null>(null);
  const [report, setReport] = useState<Report | null>(null);
  const [cycles, setCycles] = useState<Cycle[] | null>(null);
  const [est, setEst] = useState<EstimateColumns | null>(null);
  const [det, setDet] = useState<DetailColumns | null>(null);
  const [error, setError] = useState<string | null>(null);
  const [reportError, setReportError] = useState<string | null>(null);

  useEffect(() => {
    let alive = true;
    api.get<Session>(`/api/sessions/${id}`).then((s) => alive && setSession(s)).catch((e) => alive && setError(errorText(e)));
    // the robot mode's cycles and CSVs; a wearable session (contract §8) has neither
    const loadRobot = () => {
      api.get<Cycle[]>(`/api/sessions/${id}/cycles`).then((c) => alive && setCycles(c)).catch(() => alive && setCycles([]));
      getText(`/api/sessions/${id}/estimates.csv`)
        .then((t) => alive && setEst(parseEstimates(t)))
        .catch(() => undefined);
      getText(`/api/sessions/${id}/details.csv`)
        .then((t) => alive && setDet(parseDetails(t)))
        .catch(() => undefined);
    };
    api
      .get<ReportOut>(`/api/sessions/${id}/report`)
      .then((r) => {
        if (!alive) return;
        const rep = unwrapReport(r);
        setReport(rep);
        if (rep.mode !== "wearable") loadRobot();
      })
      .catch((e) => {
        if (!alive) return;
        setReportError(e instanceof ApiError && e.status === 404 ? "This session has no report (no data was recorded)." : errorText(e));
        loadRobot();
      });
    return () => {
      alive = false;
    };
  }, [id]);

  const tol = Number(report?.params?.tolerance_m ?? session?.params.tolerance_m ?? 0.1);
  const maxOut = Number(report?.params?.max_outside_fraction ?? session?.params.max_outside_fraction ?? 0.2);
  const cycleList: Cycle[] = useMemo(() => {
    if (cycles && cycles.length) return cycles;
    return (report?.cycles ?? []).map((c, i) => ({ ...c, index: c.index ?? i }));
  }, [cycles, report]);
  const t0 = est?.t[0] ?? cycleList[0]?.start ?? 0;

  const specs = useMemo(() => {
    const disp: ChartSpec = {
      title: "Shoulder displacement",
      yLabel: "cm",
      yMin: 0,
      x: "seconds",
      height: 220,
      band: () => tol * 100,
      series: [
        { label: "Displacement", color: LINE.disp, width: 1.5 },
        { label: "Tolerance", color: LINE.tol, dash: [6, 4], width: 1.5 },
      ],
    };
    const elbow: ChartSpec = { title: "Elbow angle", yLabel: "degrees", yMin: 0, x: "seconds", height: 220, series: [{ label: "Elbow angle", color: LINE.elbow, width: 1.5 }] };
    const arm: ChartSpec = {
      title: "Upper arm",
      yLabel: "degrees",
      x: "seconds",
      height: 220,
      series: [
        { label: "Elevation", color: LINE.elev, width: 1.5 },
        { label: "Azimuth", color: LINE.azim, width: 1.5 },
      ],
    };
    const cyc: ChartSpec = {
      title: "Time outside per cycle",
      yLabel: "%",
      yRange: [0, 100],
      x: "seconds",
      height: 200,
      series: [
        { label: "Time outside", color: LINE.comp, points: true, width: 1 },
        { label: "Compensatory above", color: LINE.tol, dash: [6, 4], width: 1.5 },
      ],
    };
    return { disp, elbow, arm, cyc };
  }, [tol]);

  const data = useMemo(() => {
    if (!est) return null;
    const xs = est.t.map((t) => t - t0);
    return {
      disp: [xs, est.disp, xs.map(() => tol * 100)] as AlignedData,
      elbow: [xs, est.elbow] as AlignedData,
    };
  }, [est, tol, t0]);
  const armData = useMemo(() => {
    if (!det) return null;
    return [det.t.map((t) => t - t0), det.elevation, det.azimuth] as AlignedData;
  }, [det, t0]);
  const cycData = useMemo(() => {
    const xs = cycleList.map((c) => (c.start + c.end) / 2 - t0);
    return [xs, cycleList.map((c) => c.outside_fraction * 100), xs.map(() => maxOut * 100)] as AlignedData;
  }, [cycleList, t0, maxOut]);

  if (error) return <Alert kind="error">{error}</Alert>;
  if (!session) return <p role="status">Loading the report…</p>;

  const s = report?.summary;
  const nCycles = s?.cycles ?? cycleList.length;
  const nComp = s?.compensatory_cycles ?? cycleList.filter((c) => c.compensatory).length;
  const share = s?.compensatory_share ?? (nCycles ? nComp / nCycles : null);
  const elbow = report?.elbow_flexion_deg;
  const elev = report?.upper_arm_elevation_deg;
  const azim = report?.upper_arm_azimuth_deg;
  const disp = report?.shoulder_displacement_m;
  const base = `/api/sessions/${id}`;
  // a wearable session (contract §8): joint angles, movements, no robot cycles nor verdicts
  const wearable = report?.mode === "wearable";
  const unit = wearable ? "movement" : "cycle";

  return (
    <section class="page page--report" aria-labelledby="report-title">
      <div class="page__head">
        <h1 id="report-title">
          Session report · patient <a href={`/patients/${session.patient_id}`}>{session.patient_code}</a>
        </h1>
        <span class="muted">
          {dateTime(session.started_at)} · {duration(session.started_at, session.stopped_at)} · device {session.device}
          {session.therapist ? ` · ${session.therapist}` : ""}
          {session.status === "interrupted" ? " · ⚠ interrupted" : session.status === "active" ? " · ● still running" : ""}
        </span>
      </div>

      {wearable ? (
        <div class="figures figures--row figures--key" aria-label="Summary" data-mode="wearable">
          {(report?.key_figures ?? []).slice(0, 3).map((f) => (
            <KeyFigure
              key={f.key}
              label={f.label}
              value={f.unit === "deg" ? deg(f.value) : num(f.value, f.unit === "1" ? 2 : 0, f.unit === "1" ? "" : f.unit)}
              hint={f.detail}
            />
          ))}
        </div>
      ) : (
      <div class="figures figures--row figures--key" aria-label="Summary">
        <KeyFigure
          label="Compensatory cycles"
          value={nCycles ? `${nComp} of ${nCycles}` : "–"}
          hint={nCycles ? `${pct(share)} of the cycles` : "no completed cycle"}
          tone={share === null || share === undefined ? undefined : share > 0.2 ? "warn" : "good"}
        />
        <KeyFigure label="Shoulder displacement (median)" value={cm(disp?.median)} hint={`95 % of the time below ${cm(disp?.p95)} · tolerance ${cm(tol, 0)}`} />
        <KeyFigure label="Elbow range of motion" value={deg(elbow?.range)} hint={elbow?.p5 != null && elbow?.p95 != null ? `${deg(elbow.p5)} to ${deg(elbow.p95)}` : undefined} />
      </div>
      )}

      {reportError && <Alert kind="warn">{reportError}</Alert>}

      <section class="card no-print" aria-labelledby="exports-title">
        <div class="card__head">
          <h2 id="exports-title">Export</h2>
          <div class="actions">
            <a class="btn" href={`${base}/report`} download={`session-${id}-report.json`} data-export="json">
              Report (JSON)
            </a>
            {!wearable && (
            <a class="btn" href={`${base}/estimates.csv`} download={`session-${id}-estimates.csv`} data-export="csv">
              Estimates (CSV)
            </a>
            )}
            {!wearable && (
            <a class="btn" href={`${base}/details.csv`} download={`session-${id}-details.csv`} data-export="details">
              Details (CSV)
            </a>
            )}
            <a class="btn" href={`${base}/recording.jsonl.gz`} download={`session-${id}-recording.jsonl.gz`} data-export="recording">
              Raw recording
            </a>
            <a class="btn" href={`${base}/report.pdf`} download={`session-${id}.pdf`} data-export="pdf">
              Report (PDF)
            </a>
            <a class="btn" href={`${base}/fhir`} download={`session-${id}-fhir.json`} data-export="fhir">
              FHIR R4 Bundle
            </a>
            <a class="btn" href={`${base}/recording.mcap`} download={`session-${id}.mcap`} data-export="mcap">
              MCAP (Foxglove)
            </a>
          </div>
        </div>
      </section>

      {!wearable && (
      <section class="card" aria-labelledby="plots-title">
        <h2 id="plots-title">Over the session</h2>
        {!data ? (
          <p class="muted" role="status">
            {est === null ? "Loading the estimates…" : "No estimates."}
          </p>
        ) : (
          <div class="plots">
            <StaticChart name="report-displacement" caption="Shoulder displacement (cm) with the tolerance band" spec={specs.disp} data={data.disp} />
            <StaticChart name="report-elbow" caption="Elbow angle (°)" spec={specs.elbow} data={data.elbow} />
            {armData && (
              <StaticChart
                name="report-arm"
                caption="Upper-arm elevation (0° hanging, 90° horizontal) and azimuth (°)"
                spec={specs.arm}
                data={armData}
              />
            )}
            {cycleList.length > 0 && (
              <StaticChart name="report-cycles" caption="Time outside the tolerance per cycle (%), compensatory above the dashed line" spec={specs.cyc} data={cycData} />
            )}
          </div>
        )}
      </section>
      )}

      {!wearable && (
      <section class="card" aria-labelledby="motion-title">
        <h2 id="motion-title">Range of motion</h2>
        <dl class="facts facts--grid">
          <div>
            <dt>Elbow flexion</dt>
            <dd>{elbow ? `${deg(elbow.p5)} – ${deg(elbow.p95)} (range ${deg(elbow.range)})` : "–"}</dd>
          </div>
          <div>
            <dt>Upper-arm elevation</dt>
            <dd>{elev ? `${deg(elev.p5)} – ${deg(elev.p95)} (range ${deg(elev.range)})` : "–"}</dd>
          </div>
          <div>
            <dt>Upper-arm horizontal (azimuth)</dt>
            <dd>{azim ? `${deg(azim.p5)} – ${deg(azim.p95)} (range ${deg(azim.range)})` : "–"}</dd>
          </div>
          <div>
            <dt>Cycle duration</dt>
            <dd>
              {report?.cycle_duration_s?.median != null
                ? `median ${seconds(report.cycle_duration_s.median)} (${seconds(report.cycle_duration_s.min)} – ${seconds(report.cycle_duration_s.max)})`
                : "–"}
            </dd>
          </div>
          <div>
            <dt>Time outside the tolerance</dt>
            <dd>{pct(s?.time_outside_share)}</dd>
          </div>
          <div>
            <dt>Heading calibrated after</dt>
            <dd>{report?.heading?.converged_t != null ? seconds(report.heading.converged_t - t0) : "not calibrated"}</dd>
          </div>
        </dl>
      </section>
      )}

      {report?.anatomical_rom && <AnatomicalRomSection rom={report.anatomical_rom} t0={t0} unit={unit} />}
      {report?.movement_quality && <MovementQualitySection quality={report.movement_quality} t0={t0} unit={unit} />}

      {!wearable && (
      <section class="card" aria-labelledby="cycles-title">
        <div class="card__head">
          <h2 id="cycles-title">Cycles</h2>
          <CycleCounts cycles={cycleList} />
        </div>
        <CycleTable cycles={cycleList} t0={t0} caption="Cycles with their verdicts" full />
      </section>
      )}

      <section class="card" aria-labelledby="quality-title">
        <h2 id="quality-title">Data quality</h2>
        {report?.data_quality ? (
          <dl class="facts facts--grid">
            {qualityRows(report.data_quality).map(([k, v]) => (
              <div key={k}>
                <dt>{k}</dt>
                <dd>{v}</dd>
              </div>
            ))}
          </dl>
        ) : (
          <p class="muted">No data-quality counters.</p>
        )}
      </section>
    </section>
  );
}
