// The live feed: one WebSocket (/api/ws/live or /api/ws/overlay), per-device stores with the
// last seconds of estimates, and frame-coalesced notifications (at most one per animation
// frame, however many messages arrived). A device's messages are applied in order, one
// message of rows per device per frame: rows that arrive together (network, service or
// browser jitter) are drawn in consecutive frames, not in one, so the plots move evenly. A
// message waits at most MAX_HOLD_MS for its frame (after a stall, the page catches up at once).

import { JointSeries } from "./joints";
import type {
  CycleMsg,
  EstimateRows,
  IndicatorState,
  LiveMsg,
  Num,
  StatusMsg,
} from "./types";

export const WINDOW_S = 30;
/** The longest a message of rows waits for a frame of its own, milliseconds. */
const MAX_HOLD_MS = 50;

const hasRows = (m: LiveMsg): boolean => m.type === "estimate" || m.type === "joints";

export interface Latest {
  t: number | null;
  disp: Num;
  elbow: Num;
  elev: Num;
  azim: Num;
  dx: Num;
  dy: Num;
  wristX: Num;
  wristY: Num;
  converged: boolean;
  state: IndicatorState | null;
  confidence: Num;
}

export interface Series {
  t: number[];
  disp: Num[]; // cm
  elbow: Num[];
  elev: Num[];
}

const emptyLatest = (): Latest => ({
  t: null,
  disp: null,
  elbow: null,
  elev: null,
  azim: null,
  dx: null,
  dy: null,
  wristX: null,
  wristY: null,
  converged: false,
  state: null,
  confidence: null,
});

function lastFinite(a: Num[] | undefined): Num {
  if (!a) return null;
  for (let i = a.length - 1; i >= 0; i--) {
    const v = a[i];
    if (v !== null && v !== undefined && Number.isFinite(v)) return v;
  }
  return null;
}

function at<T>(a: T[] | undefined, i: number): T | null {
  if (!a) return null;
  const v = a[i];
  return v === undefined ? null : v;
}

/** Outside and warning are one episode outside the tolerance ("outside for 2.3 s"). */
function isOut(s: IndicatorState | null): boolean {
  return s === "outside" || s === "warning";
}

export class DeviceLive {
  status: StatusMsg | null = null;
  latest: Latest = emptyLatest();
  series: Series = { t: [], disp: [], elbow: [], elev: [] };
  cycles: CycleMsg[] = [];
  /** Sample time when the current state began (for "outside for 2.3 s"). */
  stateSince: number | null = null;
  /** Recent hand (wrist cuff) positions, robot frame, metres: the overlay's game input. */
  hand: { x: number[]; y: number[] } = { x: [], y: [] };
  version = 0;
  estimates = 0;
  /** A wearable device's joint angles (contract §8) of the last WINDOW_S seconds. */
  joints = new JointSeries();

  constructor(readonly name: string) {}

  get online(): boolean {
    return this.status?.online ?? false;
  }

  /** Forget the plots and cycles (a new session begins). */
  reset(): void {
    this.joints = new JointSeries();
    this.series = { t: [], disp: [], elbow: [], elev: [] };
    this.cycles = [];
    this.latest = emptyLatest();
    this.stateSince = null;
    this.version++;
  }

  applyStatus(m: StatusMsg): void {
    const prev = this.status;
    if (prev && prev.session_id !== m.session_id) {
      this.cycles = [];
    }
    this.status = m;
    this.latest.converged = m.heading_converged;
    this.version++;
  }

  applyState(state: IndicatorState, t: number): void {
    if (isOut(state) && !isOut(this.latest.state)) this.stateSince = t;
    this.latest.state = state;
    this.version++;
  }

  applyCycle(m: CycleMsg): void {
    const idx = m.index ?? (this.cycles.at(-1)?.index ?? -1) + 1; // 0-based, as the service counts
    if (this.cycles.some((c) => c.index === idx)) return;
    this.cycles.push({ ...m, index: idx });
    if (this.cycles.length > 1000) this.cycles.splice(0, this.cycles.length - 1000);
    this.version++;
  }

  applyRows(r: EstimateRows): void {
    const n = r.t?.length ?? 0;
    if (!n) return;
    const s = this.series;
    const t0 = r.t[0]!;
    const lastT = s.t.at(-1);
    if (lastT !== undefined && t0 < lastT - 1) {
      // The device's clock went back: a new recording. Start the plots afresh.
      this.series = { t: [], disp: [], elbow: [], elev: [] };
    }
    const S = this.series;
    for (let i = 0; i < n; i++) {
      const t = r.t[i]!;
      if (S.t.length && t <= S.t[S.t.length - 1]!) continue;
      S.t.push(t);
      const d = at(r.shoulder_displacement_m, i);
      S.disp.push(d === null ? null : d * 100);
      S.elbow.push(at(r.elbow_angle_deg, i));
      S.elev.push(at(r.upper_arm_elevation_deg, i));
      const st = at(r.state, i);
      if (st && st !== this.latest.state) {
        if (isOut(st) && !isOut(this.latest.state)) this.stateSince = t;
        this.latest.state = st;
      } else if (st === null && r.state) {
        this.latest.state = null;
        this.stateSince = null;
      }
    }
    // Trim to the window (amortised: only once it is well over).
    const tEnd = S.t[S.t.length - 1]!;
    if (S.t.length > 64 && S.t[0]! < tEnd - WINDOW_S * 1.25) {
      let k = 0;
      while (k < S.t.length && S.t[k]! < tEnd - WINDOW_S) k++;
      S.t.splice(0, k);
      S.disp.splice(0, k);
      S.elbow.splice(0, k);
      S.elev.splice(0, k);
    }
    const L = this.latest;
    const i = n - 1;
    L.t = r.t[i]!;
    L.disp = at(r.shoulder_displacement_m, i);
    L.elbow = at(r.elbow_angle_deg, i);
    L.elev = at(r.upper_arm_elevation_deg, i);
    L.azim = at(r.upper_arm_azimuth_deg, i);
    L.confidence = at(r.heading_confidence, i);
    const conv = at(r.heading_converged, i);
    if (conv !== null) L.converged = conv === 1;
    let dx = at(r.dx, i);
    let dy = at(r.dy, i);
    if (dx === null || dy === null) {
      const sx = at(r.shoulder_x, i);
      const sy = at(r.shoulder_y, i);
      const nx = at(r.nominal_x, i);
      const ny = at(r.nominal_y, i);
      if (sx !== null && sy !== null && nx !== null && ny !== null) {
        dx = sx - nx;
        dy = sy - ny;
      }
    }
    L.dx = dx;
    L.dy = dy;
    L.wristX = lastFinite(r.wrist_x);
    L.wristY = lastFinite(r.wrist_y);
    if (r.wrist_x && r.wrist_y) {
      const H = this.hand;
      for (let k = 0; k < n; k++) {
        const x = r.wrist_x[k];
        const y = r.wrist_y[k];
        if (x === null || y === null || x === undefined || y === undefined) continue;
        H.x.push(x);
        H.y.push(y);
      }
      if (H.x.length > 4000) {
        H.x.splice(0, H.x.length - 3000);
        H.y.splice(0, H.y.length - 3000);
      }
    }
    this.estimates++;
    this.version++;
  }
}

export type Connection = "connecting" | "open" | "closed" | "denied";

type Listener = () => void;

/** Counters the UI tests and the benchmark read (window.__rehabLive). */
export interface LiveStats {
  messages: number;
  estimates: Record<string, number>;
  frames: Record<string, number>;
  /** animation frames in which the feed's listeners ran */
  animationFrames: number;
}

declare global {
  interface Window {
    __rehabLive?: LiveStats;
  }
}

export class LiveClient {
  readonly devices = new Map<string, DeviceLive>();
  known: string[] = [];
  connection: Connection = "connecting";
  private ws: WebSocket | null = null;
  private listeners = new Set<Listener>();
  private scheduled = false;
  private backoff = 500;
  private timer: number | undefined;
  private closed = false;
  readonly stats: LiveStats = { messages: 0, estimates: {}, frames: {}, animationFrames: 0 };
  /** per device, messages not applied yet with their arrival times (in arrival order) */
  private queues = new Map<string, { msg: LiveMsg; at: number }[]>();

  /**
   * @param path e.g. "/api/ws/live?devices=a,b" or "/api/ws/overlay"
   * @param defaultDevice for a one-device feed (the overlay): every message goes to it
   * @param onDenied the feed refused us (1008), or ended for good (see ``endsOnNormalClose``)
   * @param endsOnNormalClose a normal close (1000) by the service is the end, not a break to
   *   reconnect after: the overlay's feed closes so when its session ends, and the link is
   *   refused from then on
   */
  constructor(
    private readonly path: string,
    private readonly defaultDevice = "",
    private readonly onDenied?: () => void,
    private readonly endsOnNormalClose = false,
    /** sent first on every connection (the overlay's token: never in a URL) */
    private readonly firstMessage?: string,
  ) {
    window.__rehabLive = this.stats;
    this.connect();
  }

  device(name: string): DeviceLive {
    let d = this.devices.get(name);
    if (!d) {
      d = new DeviceLive(name);
      this.devices.set(name, d);
    }
    return d;
  }

  subscribe(fn: Listener): () => void {
    this.listeners.add(fn);
    return () => this.listeners.delete(fn);
  }

  /** Count a rendered frame for a device (the update-rate figure). */
  frameRendered(device: string): void {
    this.stats.frames[device] = (this.stats.frames[device] ?? 0) + 1;
  }

  close(): void {
    this.closed = true;
    window.clearTimeout(this.timer);
    this.ws?.close(1000);
    this.listeners.clear();
  }

  private connect(): void {
    if (this.closed) return;
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${proto}//${location.host}${this.path}`);
    this.ws = ws;
    this.connection = "connecting";
    ws.onopen = () => {
      if (this.firstMessage !== undefined) ws.send(this.firstMessage);
      this.connection = "open";
      this.backoff = 500;
      this.changed();
    };
    ws.onmessage = (ev: MessageEvent<string>) => {
      let msg: LiveMsg;
      try {
        msg = JSON.parse(ev.data) as LiveMsg;
      } catch {
        return;
      }
      this.handle(msg);
    };
    ws.onclose = (ev) => {
      this.ws = null;
      if (this.closed) return;
      if (ev.code === 1008 || (this.endsOnNormalClose && ev.code === 1000)) {
        this.connection = "denied";
        this.changed();
        this.onDenied?.();
        return;
      }
      this.connection = "closed";
      this.changed();
      this.timer = window.setTimeout(() => this.connect(), this.backoff);
      this.backoff = Math.min(this.backoff * 2, 5000);
    };
    ws.onerror = () => {
      /* onclose follows and schedules the reconnect */
    };
  }

  private nameOf(device: string | undefined): string {
    return this.defaultDevice || device || "";
  }

  private handle(msg: LiveMsg): void {
    this.stats.messages++;
    if (msg.type === "hello") {
      this.known = [...(msg.devices ?? [])].sort();
      for (const d of this.known) this.device(d);
    } else {
      const name = this.nameOf(msg.device);
      if (hasRows(msg)) this.stats.estimates[name] = (this.stats.estimates[name] ?? 0) + 1;
      let q = this.queues.get(name);
      if (!q) this.queues.set(name, (q = []));
      q.push({ msg, at: performance.now() });
    }
    this.changed();
  }

  /** Apply the queued messages: all of them, or per device up to one message of rows
   * plus those held for MAX_HOLD_MS. @returns whether messages are left for the next frame */
  private drain(all: boolean): boolean {
    const due = performance.now() - MAX_HOLD_MS;
    let left = false;
    for (const q of this.queues.values()) {
      let rows = 0;
      while (q.length) {
        const { msg, at } = q[0]!;
        if (hasRows(msg)) {
          if (rows > 0 && !all && at > due) break;
          rows++;
        }
        q.shift();
        this.apply(msg);
      }
      left ||= q.length > 0;
    }
    return left;
  }

  private apply(msg: LiveMsg): void {
    switch (msg.type) {
      case "status": {
        const d = this.device(this.nameOf(msg.device));
        d.applyStatus(msg);
        if (!this.known.includes(d.name)) this.known = [...this.known, d.name].sort();
        break;
      }
      case "estimate":
        this.device(this.nameOf(msg.device)).applyRows(msg.rows);
        break;
      case "joints": {
        const d = this.device(this.nameOf(msg.device));
        d.joints.apply(msg.rows, WINDOW_S);
        d.version++;
        break;
      }
      case "state":
        this.device(this.nameOf(msg.device)).applyState(msg.state, msg.t);
        break;
      case "cycle":
        this.device(this.nameOf(msg.device)).applyCycle(msg);
        break;
      default:
        return;
    }
  }

  private changed(): void {
    if (this.scheduled) return;
    this.scheduled = true;
    // Hidden pages get no animation frames; the game's pause logic must still run (there,
    // every 50 ms, all that came is applied at once).
    const hidden = document.hidden;
    const run = () => {
      this.scheduled = false;
      const left = this.drain(hidden);
      if (!hidden) this.stats.animationFrames++;
      this.listeners.forEach((fn) => fn());
      if (left) this.changed();
    };
    if (hidden) window.setTimeout(run, 50);
    else requestAnimationFrame(run);
  }
}
