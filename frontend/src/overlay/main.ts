// The patient's screen: a game driven by the robot's hand position, with the shoulder
// indicator in the lower right corner. Large and high-contrast, to be read from 2 m.
// Opened through the scoped link (/overlay#token=...): it only reads this device's feed.
// The token stays after "#" (never sent in a request) and goes as the socket's first message.

import "../styles.css";

import { IndicatorView } from "../lib/indicator";
import { LiveClient, type DeviceLive } from "../lib/live";
import { Game } from "./game";

const DEVICE = "overlay";
const MIN_PAUSE_MS = 3000;

const root = document.getElementById("overlay")!;
const token = new URLSearchParams(location.hash.slice(1)).get("token");
// a link of the old form (/overlay?token=...) is refused by the service: say so here
const oldLink = new URLSearchParams(location.search).has("token");

function h<K extends keyof HTMLElementTagNameMap>(tag: K, cls: string, text?: string): HTMLElementTagNameMap[K] {
  const e = document.createElement(tag);
  e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

const canvas = h("canvas", "ov-canvas");
canvas.setAttribute("aria-hidden", "true");
const top = h("div", "ov-top");
const score = h("div", "ov-score", "");
const hint = h("div", "ov-hint", "");
hint.setAttribute("role", "status");
hint.setAttribute("aria-live", "polite");
top.append(score, hint);
const banner = h("div", "ov-banner");
banner.id = "overlay-warning";
banner.setAttribute("role", "alert");
banner.hidden = true;
const bannerIcon = h("div", "ov-banner__icon", "▲");
bannerIcon.setAttribute("aria-hidden", "true");
const bannerTitle = h("div", "ov-banner__title", "");
const bannerText = h("div", "ov-banner__text", "");
const bannerStatus = h("div", "ov-banner__status", "");
banner.append(bannerIcon, bannerTitle, bannerText, bannerStatus);
const corner = h("div", "ov-indicator");
root.append(canvas, top, banner, corner);
const indicator = new IndicatorView(corner, { caption: true, distance: false });

const game = new Game();
let pausedAt = 0;
let resumedAt = 0;

function setPaused(p: boolean): void {
  game.paused = p;
  document.body.dataset.paused = String(p);
}
setPaused(false);

function showBanner(kind: "pause" | "error" | "ended" | null, title = "", text = "", status = ""): void {
  if (!kind) {
    banner.hidden = true;
    return;
  }
  banner.hidden = false;
  banner.dataset.kind = kind;
  bannerIcon.textContent = kind === "pause" ? "▲" : kind === "ended" ? "✓" : "!";
  if (bannerTitle.textContent !== title) bannerTitle.textContent = title;
  if (bannerText.textContent !== text) bannerText.textContent = text;
  if (bannerStatus.textContent !== status) bannerStatus.textContent = status;
  bannerStatus.hidden = !status;
}

if (oldLink) {
  showBanner("error", "Old link", "This link no longer works. Ask your therapist for a new link.");
} else if (!token) {
  showBanner("error", "No link", "Open this page through the link from the therapist's dashboard.");
} else {
  const client = new LiveClient(
    "/api/ws/overlay",
    DEVICE,
    () => {
      setPaused(false);
      showBanner("ended", "The session has ended", "Thank you! Ask your therapist for a new link to play again.");
    },
    true,
    JSON.stringify({ type: "auth", token }),
  );
  const dev = client.device(DEVICE);
  let lastCycles = 0;
  let learnTick = 0;
  client.subscribe(() => {
    // A compensatory cycle pauses the game until the shoulder is back inside.
    if (dev.cycles.length > lastCycles) {
      const fresh = dev.cycles.slice(lastCycles);
      lastCycles = dev.cycles.length;
      if (fresh.some((c) => c.compensatory) && !game.paused) {
        setPaused(true);
        pausedAt = performance.now();
      }
    }
    if (game.paused && dev.latest.state === "ok" && performance.now() - pausedAt > MIN_PAUSE_MS) {
      setPaused(false);
      resumedAt = performance.now();
    }
    if (++learnTick % 10 === 0) game.learn(dev.hand.x, dev.hand.y);
    if (dev.latest.wristX !== null && dev.latest.wristY !== null) game.hand(dev.latest.wristX, dev.latest.wristY);
    indicator.update({
      state: dev.latest.state,
      dx: dev.latest.dx,
      dy: dev.latest.dy,
      toleranceM: tolerance(dev),
      waitingText: dev.status && !dev.status.heading_converged ? "Getting ready" : "Waiting",
    });
    render(dev, client.connection);
  });
  window.addEventListener("resize", () => render(dev, client.connection));
}

function tolerance(dev: DeviceLive): number {
  // The overlay feed carries the displacement; the indicator's circle is the tolerance.
  const t = dev.status?.tolerance_m;
  return typeof t === "number" && t > 0 ? t : 0.1;
}

function render(dev: DeviceLive, connection: string): void {
  const now = performance.now();
  const st = dev.status;
  if (game.paused) {
    // The verdict comes at the end of a cycle: the shoulder may be back already by then.
    showBanner(
      "pause",
      "Please stop",
      "Move your shoulder back to the starting position.",
      dev.latest.state === "ok" ? "✓ It is back. Hold it there: the game goes on in a moment." : "The game goes on when it is back.",
    );
  } else if (banner.dataset.kind !== "error" && banner.dataset.kind !== "ended") {
    showBanner(null);
  }
  // Back in the game: praise where the patient looks for what to do, not over the path.
  const praise = !game.paused && resumedAt > 0 && now - resumedAt < 2500;
  score.textContent = `★ ${game.score}`;
  score.setAttribute("aria-label", `Score ${game.score}`);
  let hintText = "";
  if (praise) hintText = "✓ Well done, your shoulder is back. Carry on!";
  else if (connection === "denied") hintText = "";
  else if (connection !== "open") hintText = "Connecting…";
  else if (st && st.online === false) hintText = "The robot is not sending";
  else if (st && !st.heading_converged)
    hintText = `Getting ready: move your arm along the path · ${Math.round((st.convergence_progress ?? 0) * 100)} %`;
  else if (!game.rect) hintText = "Move your hand around the path";
  else if (!game.paused) hintText = "Collect the stars";
  if (hint.textContent !== hintText) hint.textContent = hintText;
  hint.classList.toggle("ov-hint--good", praise);
  draw(dev);
}

function draw(dev: DeviceLive): void {
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth;
  const hh = canvas.clientHeight;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(hh * dpr)) {
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(hh * dpr);
  }
  const ctx = canvas.getContext("2d");
  if (!ctx) return;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, hh);
  const r = game.rect;
  const hx = dev.latest.wristX;
  const hy = dev.latest.wristY;
  // View: the rectangle with margins, or the hand's neighbourhood before it is known.
  const cx = r ? (r.x0 + r.x1) / 2 : (hx ?? 0);
  const cy = r ? (r.y0 + r.y1) / 2 : (hy ?? 0);
  const spanX = r ? (r.x1 - r.x0) * 1.5 : 0.4;
  const spanY = r ? (r.y1 - r.y0) * 1.5 : 0.3;
  const usableW = w * 0.8;
  const usableH = hh * 0.72;
  const s = Math.min(usableW / spanX, usableH / spanY);
  const ox = w * 0.45;
  const oy = hh * 0.52;
  const X = (x: number) => ox + (x - cx) * s;
  const Y = (y: number) => oy - (y - cy) * s; // forward (+y) is up
  ctx.globalAlpha = game.paused ? 0.35 : 1;
  if (r) {
    ctx.strokeStyle = "#3d4a66";
    ctx.lineWidth = Math.max(6, game.radius * s * 1.2);
    ctx.lineJoin = "round";
    ctx.strokeRect(X(r.x0), Y(r.y1), (r.x1 - r.x0) * s, (r.y1 - r.y0) * s);
    const rad = Math.max(14, game.radius * s * 0.75);
    for (const t of game.targets) {
      if (t.collected) {
        ctx.fillStyle = "#2a3350";
        ctx.beginPath();
        ctx.arc(X(t.x), Y(t.y), rad * 0.35, 0, Math.PI * 2);
        ctx.fill();
      } else {
        star(ctx, X(t.x), Y(t.y), rad, "#F0E442");
      }
    }
  }
  if (hx !== null && hy !== null) {
    const hr = Math.max(18, Math.min(w, hh) * 0.035);
    ctx.fillStyle = "#56B4E9";
    ctx.strokeStyle = "#ffffff";
    ctx.lineWidth = 5;
    ctx.beginPath();
    ctx.arc(X(hx), Y(hy), hr, 0, Math.PI * 2);
    ctx.fill();
    ctx.stroke();
  }
  ctx.globalAlpha = 1;
}

function star(ctx: CanvasRenderingContext2D, x: number, y: number, r: number, color: string): void {
  ctx.fillStyle = color;
  ctx.strokeStyle = "#0b1020";
  ctx.lineWidth = 3;
  ctx.beginPath();
  for (let i = 0; i < 10; i++) {
    const a = -Math.PI / 2 + (i * Math.PI) / 5;
    const rr = i % 2 === 0 ? r : r * 0.45;
    ctx.lineTo(x + rr * Math.cos(a), y + rr * Math.sin(a));
  }
  ctx.closePath();
  ctx.fill();
  ctx.stroke();
}
