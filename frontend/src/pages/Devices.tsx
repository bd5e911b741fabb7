import { useEffect, useState } from "preact/hooks";

import { Alert, OnlineDot, QualityBadges } from "../components/bits";
import { useFrames, useLiveClient } from "../components/live";
import { api, errorText } from "../lib/api";
import type { Device, Quality, StatusMsg } from "../lib/types";

interface Row {
  name: string;
  online: boolean;
  status: StatusMsg | null;
  rest: Device | null;
}

export function DevicesPage() {
  const [rest, setRest] = useState<Device[] | null>(null);
  const [error, setError] = useState<string | null>(null);
  const client = useLiveClient(null);
  useFrames(client);

  useEffect(() => {
    let alive = true;
    const load = () =>
      api
        .get<Device[]>("/api/devices")
        .then((d) => alive && (setRest(d), setError(null)))
        .catch((e) => alive && setError(errorText(e)));
    load();
    const timer = window.setInterval(load, 5000);
    return () => {
      alive = false;
      window.clearInterval(timer);
    };
  }, []);

  const names = new Set<string>([...(rest ?? []).map((d) => d.name), ...client.known]);
  const rows: Row[] = [...names].sort().map((name) => {
    const live = client.devices.get(name)?.status ?? null;
    const r = rest?.find((d) => d.name === name) ?? null;
    return { name, status: live, rest: r, online: live ? live.online : r?.status === "online" };
  });
  rows.sort((a, b) => Number(b.online) - Number(a.online) || a.name.localeCompare(b.name));
  const online = rows.filter((r) => r.online).map((r) => r.name);

  return (
    <section class="page" aria-labelledby="devices-title">
      <div class="page__head">
        <h1 id="devices-title">Devices</h1>
        {online.length > 1 && (
          <a class="btn" href={`/grid?devices=${online.slice(0, 8).join(",")}`}>
            Watch {Math.min(online.length, 8)} online devices together
          </a>
        )}
      </div>
      {error && <Alert kind="error">{error}</Alert>}
      {rest === null && !error && <p role="status">Loading devices…</p>}
      {rest !== null && rows.length === 0 && (
        <p class="empty">No device has sent data yet. Switch a robot on, or run <code>rehab demo</code>.</p>
      )}
      <ul class="device-list">
        {rows.map((r) => {
          const s = r.status;
          const sessionId = s?.session_id ?? r.rest?.active_session_id ?? null;
          return (
            <li key={r.name} class={`device-card card${r.online ? "" : " device-card--off"}`} data-device={r.name}>
              <div class="device-card__head">
                <h2 class="device-card__name">
                  <a href={`/devices/${r.name}`}>{r.name}</a>
                </h2>
                <OnlineDot online={r.online} />
              </div>
              <dl class="facts">
                <div>
                  <dt>Session</dt>
                  <dd>{sessionId ? `Running · patient ${s?.patient ?? "–"}` : "None"}</dd>
                </div>
                <div>
                  <dt>Heading</dt>
                  <dd>
                    {!s || !r.online
                      ? "–"
                      : s.heading_converged
                        ? "✓ Calibrated"
                        : `Calibrating ${Math.round((s.convergence_progress ?? 0) * 100)} %`}
                  </dd>
                </div>
                <div>
                  <dt>Rates</dt>
                  <dd>
                    {s?.rates_hz && r.online
                      ? `IMU ${Math.round(s.rates_hz.imu ?? 0)} Hz · robot ${Math.round(s.rates_hz.robot ?? 0)} Hz`
                      : "–"}
                  </dd>
                </div>
              </dl>
              <QualityBadges quality={(s?.quality ?? (r.rest?.stats as Quality | null)) || null} online={r.online} />
              <a class="btn btn--primary" href={`/devices/${r.name}`} aria-label={`Open ${r.name}`}>
                {sessionId ? "Open live session" : "Open"}
              </a>
            </li>
          );
        })}
      </ul>
    </section>
  );
}
