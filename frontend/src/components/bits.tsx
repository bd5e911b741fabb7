import type { ComponentChildren } from "preact";

import { qualityBadges, type Badge } from "../lib/quality";
import type { Cycle, Quality } from "../lib/types";
import { pct, seconds } from "../lib/format";

export function Badges({ badges }: { badges: Badge[] }) {
  return (
    <ul class="badges" aria-label="Data quality">
      {badges.map((b) => (
        <li key={b.label} class={`badge badge--${b.tone}`} title={b.title}>
          {b.label}
        </li>
      ))}
    </ul>
  );
}

export function QualityBadges({ quality, online }: { quality: Quality | null | undefined; online: boolean }) {
  return <Badges badges={qualityBadges(quality, online)} />;
}

export function OnlineDot({ online }: { online: boolean }) {
  return (
    <span class={online ? "online online--yes" : "online online--no"}>
      <span class="online__dot" aria-hidden="true">
        {online ? "●" : "○"}
      </span>
      {online ? "Online" : "Offline"}
    </span>
  );
}

export function KeyFigure({
  label,
  value,
  hint,
  tone,
}: {
  label: string;
  value: ComponentChildren;
  hint?: ComponentChildren;
  tone?: "good" | "warn" | "bad";
}) {
  return (
    <div class={`figure${tone ? ` figure--${tone}` : ""}`}>
      <div class="figure__label">{label}</div>
      <div class="figure__value">{value}</div>
      {hint && <div class="figure__hint">{hint}</div>}
    </div>
  );
}

export function Verdict({ compensatory }: { compensatory: boolean }) {
  return compensatory ? (
    <span class="verdict verdict--comp">
      <span aria-hidden="true">✗ </span>Compensatory
    </span>
  ) : (
    <span class="verdict verdict--ok">
      <span aria-hidden="true">✓ </span>Proper
    </span>
  );
}

export function CycleCounts({ cycles }: { cycles: Pick<Cycle, "compensatory">[] }) {
  const comp = cycles.filter((c) => c.compensatory).length;
  return (
    <p class="cycle-counts" aria-live="polite">
      <strong>{cycles.length}</strong> cycles · <span class="verdict verdict--ok">✓ {cycles.length - comp} proper</span> ·{" "}
      <span class="verdict verdict--comp">✗ {comp} compensatory</span>
    </p>
  );
}

export function CycleTable({
  cycles,
  t0 = 0,
  newestFirst = false,
  limit,
  caption,
  full = false,
}: {
  cycles: Cycle[];
  t0?: number;
  newestFirst?: boolean;
  limit?: number;
  caption: string;
  /** every row on the page (a report), not in a scrolling box (a live list) */
  full?: boolean;
}) {
  let rows = newestFirst ? [...cycles].reverse() : cycles;
  if (limit) rows = rows.slice(0, limit);
  return (
    <div class={full ? "table-wrap table-wrap--full" : "table-wrap"} tabIndex={full ? undefined : 0} role="region" aria-label={caption}>
      <table class="table">
        <caption class="sr-only">{caption}</caption>
        <thead>
          <tr>
            <th scope="col">Cycle</th>
            <th scope="col">Start</th>
            <th scope="col">Duration</th>
            <th scope="col">Time outside</th>
            <th scope="col">Verdict</th>
          </tr>
        </thead>
        <tbody>
          {rows.map((c) => (
            <tr key={c.index} class={c.compensatory ? "row--comp" : undefined}>
              <td>{c.index + 1}</td>
              <td>{seconds(c.start - t0)}</td>
              <td>{seconds(c.end - c.start)}</td>
              <td>{pct(c.outside_fraction)}</td>
              <td>
                <Verdict compensatory={c.compensatory} />
              </td>
            </tr>
          ))}
          {!rows.length && (
            <tr>
              <td colSpan={5} class="muted">
                No completed cycle yet.
              </td>
            </tr>
          )}
        </tbody>
      </table>
    </div>
  );
}

export function Alert({ kind, children }: { kind: "error" | "info" | "warn"; children: ComponentChildren }) {
  return (
    <p class={`alert alert--${kind}`} role={kind === "error" ? "alert" : "status"}>
      {children}
    </p>
  );
}

export function ConnectionNote({ connection }: { connection: string }) {
  if (connection === "open") return null;
  const text =
    connection === "connecting"
      ? "Connecting to the live feed…"
      : connection === "denied"
        ? "The live feed refused the connection: log in again."
        : "Live feed interrupted: reconnecting…";
  return <Alert kind="warn">{text}</Alert>;
}
