import { useEffect, useMemo, useState } from "preact/hooks";

import { Alert, ConnectionNote, OnlineDot } from "../components/bits";
import { IndicatorBox, LivePlots, useFrames, useLiveClient } from "../components/live";
import { api, errorText } from "../lib/api";
import { num } from "../lib/format";
import type { DeviceLive, LiveClient } from "../lib/live";
import type { Device } from "../lib/types";

function Cell({ client, dev }: { client: LiveClient; dev: DeviceLive }) {
  const st = dev.status;
  const L = dev.latest;
  const comp = dev.cycles.filter((c) => c.compensatory).length;
  const tol = st?.tolerance_m ?? 0.1;
  return (
    <section class="card grid-cell" aria-labelledby={`cell-${dev.name}`} data-device={dev.name}>
      <div class="card__head">
        <h2 id={`cell-${dev.name}`}>
          <a href={`/devices/${dev.name}`}>{dev.name}</a>
        </h2>
        <OnlineDot online={dev.online} />
      </div>
      <p class="muted small">
        {st?.session_id ? `Patient ${st.patient ?? "–"}` : "No session"}
        {st && st.online && !st.heading_converged ? ` · calibrating ${Math.round((st.convergence_progress ?? 0) * 100)} %` : ""}
      </p>
      <div class="grid-cell__body">
        <IndicatorBox dev={dev} tolerance={tol} compact />
        <div class="grid-cell__numbers">
          <div class="big-number" aria-label="Shoulder displacement">
            {num(L.disp !== null ? L.disp * 100 : null, 1)}
            <span class="unit">cm</span>
          </div>
          <div class="small">
            Elbow {num(L.elbow, 0, "°")} · elevation {num(L.elev, 0, "°")}
          </div>
          <div class="small">
            {dev.cycles.length} cycles · <span class="verdict verdict--comp">✗ {comp}</span>
          </div>
        </div>
      </div>
      <LivePlots client={client} dev={dev} tolerance={tol} show={{ disp: true }} height={120} />
    </section>
  );
}

export function GridPage({ devices }: { devices: string | null }) {
  const [names, setNames] = useState<string[] | null>(devices ? devices.split(",").filter(Boolean) : null);
  const [error, setError] = useState<string | null>(null);
  useEffect(() => {
    if (devices) {
      setNames(devices.split(",").filter(Boolean));
      return;
    }
    api
      .get<Device[]>("/api/devices")
      .then((d) => {
        const online = d.filter((x) => x.status === "online").map((x) => x.name);
        setNames((online.length ? online : d.map((x) => x.name)).slice(0, 8));
      })
      .catch((e) => setError(errorText(e)));
  }, [devices]);
  const list = useMemo(() => names ?? [], [names?.join(",")]);
  const client = useLiveClient(list.length ? list : ["-"]);
  useFrames(client);

  return (
    <section class="page" aria-labelledby="grid-title">
      <div class="page__head">
        <h1 id="grid-title">All devices live</h1>
        <span class="muted">{list.length} devices</span>
      </div>
      <ConnectionNote connection={client.connection} />
      {error && <Alert kind="error">{error}</Alert>}
      {names && names.length === 0 && <p class="empty">No devices yet.</p>}
      <div class="device-grid">
        {list.map((n) => (
          <Cell key={n} client={client} dev={client.device(n)} />
        ))}
      </div>
    </section>
  );
}
