import { useEffect, useLayoutEffect, useMemo, useRef, useState } from "preact/hooks";
import type { AlignedData } from "uplot";

import { IndicatorView } from "../lib/indicator";
import { DeviceLive, LiveClient, WINDOW_S } from "../lib/live";
import { Chart, LINE } from "../lib/plots";
import type { StatusMsg } from "../lib/types";

/** A live feed for the page's lifetime; `devices` null = every device. */
export function useLiveClient(devices: string[] | null): LiveClient {
  const key = devices ? devices.join(",") : "*";
  const client = useMemo(
    () => new LiveClient(devices ? `/api/ws/live?devices=${encodeURIComponent(key)}` : "/api/ws/live"),
    [key],
  );
  useEffect(() => () => client.close(), [client]);
  return client;
}

/** Re-render on every frame in which the feed changed. */
export function useFrames(client: LiveClient): number {
  const [n, setN] = useState(0);
  useEffect(() => client.subscribe(() => setN((x) => x + 1)), [client]);
  return n;
}

export function waitingText(status: StatusMsg | null): string {
  if (!status || !status.online) return "Device offline";
  if (!status.heading_converged) return "Move the arm: calibrating";
  return "Waiting for the nominal shoulder";
}

export function IndicatorBox({
  dev,
  tolerance,
  compact = false,
}: {
  dev: DeviceLive;
  tolerance: number;
  compact?: boolean;
}) {
  const ref = useRef<HTMLDivElement>(null);
  const view = useRef<IndicatorView | null>(null);
  useEffect(() => {
    view.current = new IndicatorView(ref.current!, { compact });
    return () => view.current?.destroy();
  }, [compact]);
  useLayoutEffect(() => {
    const L = dev.latest;
    view.current?.update({
      state: L.state,
      dx: L.dx,
      dy: L.dy,
      toleranceM: tolerance,
      waitingText: waitingText(dev.status),
    });
  });
  return <div ref={ref} class="indicator-host" />;
}

export interface PlotSet {
  disp?: boolean;
  elbow?: boolean;
  elev?: boolean;
}

/** Live uPlot charts of the last WINDOW_S seconds: displacement with the tolerance band,
 * elbow angle, upper-arm elevation. Updated in place when the device's data changed. */
export function LivePlots({
  client,
  dev,
  tolerance,
  show = { disp: true, elbow: true, elev: true },
  height = 170,
}: {
  client: LiveClient;
  dev: DeviceLive;
  tolerance: number;
  show?: PlotSet;
  height?: number;
}) {
  const dispRef = useRef<HTMLDivElement>(null);
  const elbowRef = useRef<HTMLDivElement>(null);
  const elevRef = useRef<HTMLDivElement>(null);
  const charts = useRef<{ disp?: Chart; elbow?: Chart; elev?: Chart }>({});
  const tolRef = useRef(tolerance);
  tolRef.current = tolerance;
  const seen = useRef(-1);

  useEffect(() => {
    const empty: AlignedData = [[], []];
    const c = charts.current;
    if (show.disp && dispRef.current) {
      c.disp = new Chart(
        dispRef.current,
        {
          title: "Shoulder displacement",
          yLabel: "cm",
          yMin: 0,
          height,
          band: () => tolRef.current * 100,
          series: [
            { label: "Displacement", color: LINE.disp },
            { label: "Tolerance", color: LINE.tol, dash: [6, 4], width: 1.5 },
          ],
        },
        [[], [], []],
      );
    }
    if (show.elbow && elbowRef.current) {
      c.elbow = new Chart(
        elbowRef.current,
        { title: "Elbow angle", yLabel: "degrees", yRange: [0, 150], height, series: [{ label: "Elbow angle", color: LINE.elbow }] },
        empty,
      );
    }
    if (show.elev && elevRef.current) {
      c.elev = new Chart(
        elevRef.current,
        { title: "Upper-arm elevation", yLabel: "degrees", yRange: [-10, 120], height, series: [{ label: "Upper-arm elevation", color: LINE.elev }] },
        empty,
      );
    }
    return () => {
      c.disp?.destroy();
      c.elbow?.destroy();
      c.elev?.destroy();
      charts.current = {};
    };
  }, [show.disp, show.elbow, show.elev, height]);

  useEffect(
    () =>
      client.subscribe(() => {
        if (dev.version === seen.current) return;
        seen.current = dev.version;
        const s = dev.series;
        const c = charts.current;
        const tEnd = s.t.length ? s.t[s.t.length - 1]! : 0;
        const xs = s.t;
        const win: [number, number] = [tEnd - WINDOW_S, tEnd];
        if (c.disp) {
          const tol = tolRef.current * 100;
          c.disp.setData([xs, s.disp, xs.map(() => tol)], win);
        }
        if (c.elbow) {
          c.elbow.setData([xs, s.elbow], win);
        }
        if (c.elev) {
          c.elev.setData([xs, s.elev], win);
        }
        client.frameRendered(dev.name);
      }),
    [client, dev],
  );

  return (
    <div class="plots">
      {show.disp && (
        <figure class="plot">
          <figcaption>Shoulder displacement (cm) with the tolerance band</figcaption>
          <div ref={dispRef} class="plot__canvas" data-plot="displacement" />
        </figure>
      )}
      {show.elbow && (
        <figure class="plot">
          <figcaption>Elbow angle (°, 0 = extended)</figcaption>
          <div ref={elbowRef} class="plot__canvas" data-plot="elbow" />
        </figure>
      )}
      {show.elev && (
        <figure class="plot">
          <figcaption>Upper-arm elevation (°)</figcaption>
          <div ref={elevRef} class="plot__canvas" data-plot="elevation" />
        </figure>
      )}
    </div>
  );
}
