import { useEffect, useState } from "preact/hooks";

import { api, errorText } from "../lib/api";

interface VizInfo {
  enabled: boolean;
  port: number | null;
  path: string | null;
  device: string | null;
}

/** The live 3D arm (viser on the backend's loopback, framed through the API's authenticated
 * proxy path ``info.path``), for one device. */
export function Viz3D({ device }: { device: string }) {
  const [open, setOpen] = useState(() => localStorage.getItem("rehab.viz") !== "closed");
  const [info, setInfo] = useState<VizInfo | null>(null);
  const [error, setError] = useState<string | null>(null);

  useEffect(() => {
    localStorage.setItem("rehab.viz", open ? "open" : "closed");
    if (!open) return;
    let alive = true;
    api
      .put<VizInfo>("/api/viz/device", { device })
      .then((i) => alive && setInfo(i))
      .catch((e) => alive && setError(errorText(e)));
    return () => {
      alive = false;
    };
  }, [open, device]);

  let src: string | null = null;
  if (info?.enabled) {
    if (info.path) src = info.path;
    else if (info.port) src = `${location.protocol}//${location.hostname}:${info.port}/`;
  }
  return (
    <section class="card viz" aria-labelledby="viz-title">
      <div class="card__head">
        <h2 id="viz-title">3D view</h2>
        <button type="button" class="btn btn--ghost" aria-expanded={open} onClick={() => setOpen(!open)}>
          {open ? "Hide 3D view" : "Show 3D view"}
        </button>
      </div>
      {open && (
        <>
          {error && <p class="muted">3D view unavailable: {error}</p>}
          {info && !info.enabled && <p class="muted">The 3D view is switched off on this service.</p>}
          {src && (
            <iframe
              class="viz__frame"
              src={src}
              title={`3D view of ${device}'s arm: shoulder, elbow, wrist, IMU, robot cuffs and ropes`}
            />
          )}
          <p class="muted small">
            Gray ring: tolerance around the nominal shoulder. Trace: recent shoulder positions, green inside, blue outside,
            orange when out too long. Drag to turn the view.
          </p>
        </>
      )}
    </section>
  );
}
