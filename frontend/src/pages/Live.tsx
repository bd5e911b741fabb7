import { useEffect, useMemo, useState } from "preact/hooks";

import { Alert, ConnectionNote, CycleCounts, CycleTable, KeyFigure, OnlineDot, QualityBadges } from "../components/bits";
import { IndicatorBox, LivePlots, useFrames, useLiveClient } from "../components/live";
import { Viz3D } from "../components/Viz3D";
import { JointFigures, JointPlots, RomTestPanel, WearableNotes } from "../components/Wearable";
import { api, errorText } from "../lib/api";
import { dateTime, duration, num, warningAfter } from "../lib/format";
import type { DeviceLive } from "../lib/live";
import type { Cycle, Device, NominalShoulder, OverlayLink, Patient, Session } from "../lib/types";

/** Where the nominal shoulder came from, in plain words. */
function nominalSource(nom: NominalShoulder): string {
  const by = nom.set_by ? ` by ${nom.set_by}` : "";
  switch (nom.source) {
    case "auto":
      return "set automatically";
    case "estimate":
      return `set here${by}`;
    case "therapist":
      return `set${by}`;
    case "params":
      return "taken from the patient's settings";
    case "event":
      return "set from the robot's shoulder reference";
    default:
      return "set";
  }
}

function Calibration({
  dev,
  session,
  onSession,
}: {
  dev: DeviceLive;
  session: Session;
  onSession: (s: Session) => void;
}) {
  const [busy, setBusy] = useState(false);
  const [error, setError] = useState<string | null>(null);
  const st = dev.status;
  const converged = st?.heading_converged ?? dev.latest.converged;
  const progress = Math.max(0, Math.min(1, st?.convergence_progress ?? 0));

  const act = async (fn: () => Promise<Session>) => {
    setBusy(true);
    setError(null);
    try {
      onSession(await fn());
    } catch (e) {
      setError(errorText(e));
    } finally {
      setBusy(false);
    }
  };

  if (!converged) {
    const pctDone = Math.round(progress * 100);
    return (
      <section class="card calib calib--pending" aria-labelledby="calib-title">
        <h2 id="calib-title">
          <span aria-hidden="true">↻ </span>Move the arm
        </h2>
        <p>
          The heading is being estimated. Ask the patient to move the arm along the task path; feedback starts once
          calibration is complete.
        </p>
        <div class="progress" role="progressbar" aria-label="Calibration progress" aria-valuemin={0} aria-valuemax={100} aria-valuenow={pctDone}>
          <div class="progress__bar" style={{ width: `${pctDone}%` }} />
        </div>
        <p class="progress__text">{pctDone} % calibrated</p>
      </section>
    );
  }
  const nom = session.nominal_shoulder;
  const conf = st?.heading_confidence;
  return (
    <section class="card calib calib--done" aria-labelledby="calib-title">
      <h2 id="calib-title">
        <span aria-hidden="true">✓ </span>Calibrated
      </h2>
      <p>
        Heading converged{conf !== undefined && conf !== null ? ` (confidence ${Math.round(conf * 100)} %)` : ""}.{" "}
        {nom
          ? `Nominal shoulder ${nominalSource(nom)} at ${dateTime(nom.set_at)}.`
          : dev.latest.state
            ? "Nominal shoulder set automatically."
            : "Nominal shoulder not set yet."}
      </p>
      <div class="actions">
        <button
          type="button"
          class="btn btn--primary"
          disabled={busy}
          onClick={() => act(() => api.put<Session>(`/api/sessions/${session.id}/nominal-shoulder`, { source: "estimate" }))}
        >
          Set nominal shoulder here
        </button>
        <button
          type="button"
          class="btn"
          disabled={busy}
          onClick={() => act(() => api.del<Session>(`/api/sessions/${session.id}/nominal-shoulder`))}
        >
          Reset to automatic
        </button>
      </div>
      {error && <Alert kind="error">{error}</Alert>}
    </section>
  );
}

function StartSession({
  device,
  online,
  wearable,
  onStarted,
}: {
  device: string;
  online: boolean;
  wearable: boolean;
  onStarted: (s: Session) => void;
}) {
  const [patients, setPatients] = useState<Patient[] | null>(null);
  const [pick, setPick] = useState<string>(() => new URLSearchParams(location.search).get("patient") ?? "");
  const [error, setError] = useState<string | null>(null);
  const [busy, setBusy] = useState(false);

  useEffect(() => {
    api
      .get<Patient[]>("/api/patients?limit=1000")
      .then((p) => {
        setPatients(p);
        if (!pick && p.length === 1) setPick(String(p[0]!.id));
      })
      .catch((e) => setError(errorText(e)));
  }, []);

  const start = async (ev: Event) => {
    ev.preventDefault();
    if (!pick) return;
    setBusy(true);
    setError(null);
    try {
      // a wearable device (its streams, contract §8): a wearable session on the patient's arm
      const side = patients?.find((p) => String(p.id) === pick)?.affected_side;
      const body = wearable ? { patient_id: Number(pick), device, wearable: { side } } : { patient_id: Number(pick), device };
      onStarted(await api.post<Session>("/api/sessions", body));
    } catch (e) {
      setError(errorText(e));
    } finally {
      setBusy(false);
    }
  };

  return (
    <form class="card session-bar" onSubmit={start} aria-labelledby="start-title">
      <h2 id="start-title">Start a session</h2>
      {patients && patients.length === 0 ? (
        <p>
          No patients yet. <a href="/patients">Create a patient</a> first.
        </p>
      ) : (
        <div class="session-bar__row">
          <label class="field field--inline">
            <span>Patient</span>
            <select value={pick} onChange={(e) => setPick(e.currentTarget.value)} required name="patient">
              <option value="">Choose a patient…</option>
              {(patients ?? []).map((p) => (
                <option key={p.id} value={String(p.id)}>
                  {p.code} · {p.affected_side} arm · tolerance {Math.round(p.tolerance_m * 100)} cm
                </option>
              ))}
            </select>
          </label>
          <button type="submit" class="btn btn--primary" disabled={busy || !pick}>
            {busy ? "Starting…" : "Start session"}
          </button>
          <a href="/patients" class="btn btn--ghost">
            New patient
          </a>
        </div>
      )}
      {!online && <p class="muted">The device is offline: a session can start once it sends data.</p>}
      {error && <Alert kind="error">{error}</Alert>}
    </form>
  );
}

function OverlayLinkBox({ session }: { session: Session }) {
  const [link, setLink] = useState<OverlayLink | null>(null);
  const [error, setError] = useState<string | null>(null);
  const [copied, setCopied] = useState(false);
  const make = async () => {
    setError(null);
    try {
      setLink(await api.post<OverlayLink>(`/api/sessions/${session.id}/overlay-link`));
    } catch (e) {
      setError(errorText(e));
    }
  };
  const url = link ? `${location.origin}${link.path}` : "";
  return (
    <div class="overlay-link">
      {!link ? (
        <button type="button" class="btn" onClick={make}>
          Patient screen link
        </button>
      ) : (
        <div class="overlay-link__box">
          <label class="field field--inline">
            <span>Patient screen</span>
            <input readOnly value={url} onFocus={(e) => e.currentTarget.select()} aria-label="Overlay link for the patient's screen" />
          </label>
          <button
            type="button"
            class="btn"
            onClick={async () => {
              try {
                await navigator.clipboard.writeText(url);
                setCopied(true);
              } catch {
                setCopied(false);
              }
            }}
          >
            {copied ? "Copied" : "Copy"}
          </button>
          <a class="btn" href={link.path} target="_blank" rel="noopener" data-external>
            Open
          </a>
        </div>
      )}
      {error && <Alert kind="error">{error}</Alert>}
    </div>
  );
}

export function LivePage({ device }: { device: string }) {
  const devices = useMemo(() => [device], [device]);
  const client = useLiveClient(devices);
  useFrames(client);
  const dev = client.device(device);
  const [rest, setRest] = useState<Device | null>(null);
  const [session, setSession] = useState<Session | null>(null);
  const [stopped, setStopped] = useState<Session | null>(null);
  const [pastCycles, setPastCycles] = useState<Cycle[]>([]);
  const [error, setError] = useState<string | null>(null);
  const [busy, setBusy] = useState(false);
  const [, tick] = useState(0);

  // A device that has not sent data yet is not an error: the page waits for it and reads
  // the device again once the live feed hears from it.
  const [unknown, setUnknown] = useState(false);
  const heard = dev.status !== null;
  const load = () =>
    api
      .get<Device>(`/api/devices/${device}`)
      .then((d) => {
        setRest(d);
        setUnknown(false);
      })
      .catch((e) => (e?.status === 404 ? setUnknown(true) : setError(errorText(e))));
  useEffect(() => {
    load();
  }, [device]);
  useEffect(() => {
    if (heard && unknown) load(); // read again only a device that was unknown
  }, [heard, unknown]);

  const liveSessionId = dev.status ? dev.status.session_id : (rest?.active_session_id ?? null);
  useEffect(() => {
    if (liveSessionId === null) {
      setSession((s) => (s && s.status === "active" ? null : s));
      return;
    }
    if (session?.id === liveSessionId) return;
    api
      .get<Session>(`/api/sessions/${liveSessionId}`)
      .then((s) => {
        setSession(s);
        setStopped(null);
        return api.get<Cycle[]>(`/api/sessions/${s.id}/cycles`);
      })
      .then(setPastCycles)
      .catch((e) => setError(errorText(e)));
  }, [liveSessionId]);

  useEffect(() => {
    const t = window.setInterval(() => tick((x) => x + 1), 1000);
    return () => window.clearInterval(t);
  }, []);

  const active = session && session.status === "active" ? session : null;
  const tolerance = Number(active?.params.tolerance_m ?? 0.1);
  const online = dev.status ? dev.status.online : rest?.status === "online";

  const cycles: Cycle[] = useMemo(() => {
    if (!active) return [];
    const byIndex = new Map<number, Cycle>();
    for (const c of pastCycles) byIndex.set(c.index, c);
    for (const c of dev.cycles) if (c.index !== undefined) byIndex.set(c.index, { ...c, index: c.index });
    return [...byIndex.values()].sort((a, b) => a.index - b.index);
  }, [active?.id, pastCycles, dev.cycles.length]);

  const stop = async () => {
    if (!active) return;
    setBusy(true);
    setError(null);
    try {
      const s = await api.post<Session>(`/api/sessions/${active.id}/stop`);
      setStopped(s);
      setSession(s);
    } catch (e) {
      setError(errorText(e));
    } finally {
      setBusy(false);
    }
  };

  const wearable = dev.status?.mode === "wearable" || active?.params.mode === "wearable";
  const L = dev.latest;
  const outsideFor = L.state && L.state !== "ok" && dev.stateSince !== null && L.t !== null ? L.t - dev.stateSince : null;

  return (
    <section class="page page--live" aria-labelledby="live-title">
      <div class="page__head">
        <h1 id="live-title">{device}</h1>
        <OnlineDot online={online} />
        <QualityBadges quality={dev.status?.quality ?? null} online={online} />
        {dev.status?.rates_hz && online && (
          <span class="muted small">
            IMU {Math.round(dev.status.rates_hz.imu ?? 0)} Hz · robot {Math.round(dev.status.rates_hz.robot ?? 0)} Hz
          </span>
        )}
      </div>
      <ConnectionNote connection={client.connection} />
      {error && <Alert kind="error">{error}</Alert>}
      {unknown && !heard && (
        <Alert kind="info">Device {device} has not sent data yet. This page goes live when it does.</Alert>
      )}
      {stopped && (
        <Alert kind="info">
          Session stopped. <a href={`/sessions/${stopped.id}`}>Open the report</a>
        </Alert>
      )}

      {active ? (
        <div class="card session-bar" aria-label="Session">
          <div class="session-bar__row">
            <div class="session-bar__who">
              <span class="muted">Patient</span>{" "}
              <a href={`/patients/${active.patient_id}`} class="strong">
                {active.patient_code}
              </a>
              <span class="muted"> · started {dateTime(active.started_at)} · </span>
              <span class="strong" aria-label="Elapsed">
                {duration(active.started_at, null)}
              </span>
            </div>
            <OverlayLinkBox session={active} />
            <button type="button" class="btn btn--danger" onClick={stop} disabled={busy}>
              {busy ? "Stopping…" : "Stop session"}
            </button>
          </div>
        </div>
      ) : (
        <StartSession
          device={device}
          online={online}
          wearable={wearable}
          onStarted={(s) => {
            dev.reset();
            setPastCycles([]);
            setStopped(null);
            setSession(s);
          }}
        />
      )}

      {wearable && <WearableNotes dev={dev} />}
      {active && !wearable && <Calibration dev={dev} session={active} onSession={setSession} />}

      {wearable ? (
        <div class="live-grid live-grid--wearable">
          <section class="card" aria-labelledby="joints-title">
            <h2 id="joints-title">Joint angles</h2>
            <JointFigures dev={dev} />
            {active && <RomTestPanel dev={dev} session={active} />}
          </section>
          <section class="card live-plots" aria-labelledby="plots-title">
            <h2 id="plots-title">Last 30 seconds</h2>
            <JointPlots client={client} dev={dev} />
          </section>
        </div>
      ) : (
      <div class="live-grid">
        <section class="card live-indicator" aria-labelledby="ind-title">
          <h2 id="ind-title">Shoulder</h2>
          <IndicatorBox dev={dev} tolerance={tolerance} />
          <div class="figures">
            <KeyFigure label="Displacement" value={num(L.disp !== null ? L.disp * 100 : null, 1, "cm")} hint={`tolerance ${Math.round(tolerance * 100)} cm`} />
            <KeyFigure label="Elbow angle" value={num(L.elbow, 0, "°")} />
            <KeyFigure label="Upper-arm elevation" value={num(L.elev, 0, "°")} />
            <KeyFigure label="Outside for" value={outsideFor !== null ? num(outsideFor, 1, "s") : "–"} hint={active ? warningAfter(active.params.warning_after_s, active.params.max_outside_fraction) : undefined} />
          </div>
        </section>
        <section class="card live-plots" aria-labelledby="plots-title">
          <h2 id="plots-title">Last 30 seconds</h2>
          <LivePlots client={client} dev={dev} tolerance={tolerance} />
        </section>
      </div>
      )}

      {active && !wearable && (
        <section class="card" aria-labelledby="cycles-title">
          <div class="card__head">
            <h2 id="cycles-title">Cycles</h2>
            <CycleCounts cycles={cycles} />
          </div>
          <CycleTable cycles={cycles} newestFirst limit={50} t0={cycles[0]?.start ?? 0} caption="Completed cycles, newest first" />
        </section>
      )}

      <Viz3D device={device} />
    </section>
  );
}
