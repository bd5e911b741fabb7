// The shoulder indicator of the seed paper's Figure 5, drawn as SVG and updated in place.
//
// Top view of the horizontal plane around the nominal shoulder: a gray circle is the
// tolerance, the current shoulder a small marker, green inside and blue outside; the
// background turns orange once the shoulder has been outside for longer than tolerated.
// Readable without colour too: each state has its own marker shape (circle, diamond,
// triangle), an icon and a text label. Colours: Okabe–Ito (colour-blind safe).

import type { IndicatorState } from "./types";

export const COLORS = {
  ok: "#009E73", // bluish green
  outside: "#0072B2", // blue
  warning: "#E69F00", // orange
  waiting: "#6b7280",
} as const;

export const LABELS: Record<IndicatorState | "waiting", { title: string; icon: string }> = {
  ok: { title: "OK", icon: "✓" },
  outside: { title: "Outside", icon: "◆" },
  warning: { title: "Warning", icon: "▲" },
  waiting: { title: "Waiting", icon: "…" },
};

export interface IndicatorInput {
  state: IndicatorState | null;
  /** shoulder − nominal, horizontal, metres (robot frame: x lateral, y forward) */
  dx: number | null;
  dy: number | null;
  toleranceM: number;
  /** why the indicator waits (shown when state is null) */
  waitingText?: string;
}

const NS = "http://www.w3.org/2000/svg";
const R = 50; // tolerance radius in view units; the view spans ±100 (two tolerances)

function el<K extends keyof SVGElementTagNameMap>(
  name: K,
  attrs: Record<string, string | number>,
  parent?: Element,
): SVGElementTagNameMap[K] {
  const e = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
  parent?.appendChild(e);
  return e;
}

export function stateKey(s: IndicatorState | null): IndicatorState | "waiting" {
  return s ?? "waiting";
}

export class IndicatorView {
  readonly root: HTMLDivElement;
  private bg: SVGRectElement;
  private marker: SVGGElement;
  private shapes: Record<"ok" | "outside" | "warning", SVGGElement>;
  private trail: SVGPolylineElement;
  private label: HTMLDivElement;
  private labelIcon: HTMLSpanElement;
  private labelText: HTMLSpanElement;
  private sub: HTMLDivElement;
  private lastKey = "";
  private lastPos = "";
  private trailPts: [number, number][] = [];
  private readonly distance: boolean;

  /** ``compact``: a small one (several devices on a screen); ``distance``: the caption says
   * how far the shoulder is (not when the distance is shown beside it, or for the patient). */
  constructor(parent: HTMLElement, opts: { compact?: boolean; caption?: boolean; distance?: boolean } = {}) {
    this.distance = opts.distance ?? !opts.compact;
    this.root = document.createElement("div");
    this.root.className = "indicator" + (opts.compact ? " indicator--compact" : "");
    const svg = el("svg", {
      viewBox: "-100 -100 200 200",
      class: "indicator__svg",
      "aria-hidden": "true",
      focusable: "false",
    });
    this.root.appendChild(svg);
    this.bg = el("rect", { x: -100, y: -100, width: 200, height: 200, rx: 14, class: "ind-bg" }, svg);
    el("line", { x1: -96, y1: 0, x2: 96, y2: 0, class: "ind-axis" }, svg);
    el("line", { x1: 0, y1: -96, x2: 0, y2: 96, class: "ind-axis" }, svg);
    el("circle", { cx: 0, cy: 0, r: R, class: "ind-tol" }, svg);
    el("circle", { cx: 0, cy: 0, r: 3, class: "ind-centre" }, svg);
    // In the corner, out of the marker's reach (it stops at 88 from the centre).
    const fwd = el("text", { x: -94, y: -86, class: "ind-fwd", "text-anchor": "start" }, svg);
    fwd.textContent = "↑ forward";
    this.trail = el("polyline", { points: "", class: "ind-trail" }, svg);
    this.marker = el("g", { class: "ind-marker" }, svg);
    const ok = el("g", {}, this.marker);
    el("circle", { r: 11, fill: COLORS.ok, class: "ind-shape" }, ok);
    el("path", { d: "M-5 0.5 L-1.5 4.5 L5.5 -4", class: "ind-glyph" }, ok);
    const outside = el("g", {}, this.marker);
    el("rect", { x: -9, y: -9, width: 18, height: 18, transform: "rotate(45)", fill: COLORS.outside, class: "ind-shape" }, outside);
    el("path", { d: "M0 -5.5 L0 1.5 M0 5 L0 5.6", class: "ind-glyph" }, outside);
    const warning = el("g", {}, this.marker);
    el("path", { d: "M0 -14 L13 10 L-13 10 Z", fill: COLORS.outside, class: "ind-shape" }, warning);
    el("path", { d: "M0 -6 L0 2 M0 5.5 L0 6", class: "ind-glyph" }, warning);
    this.shapes = { ok, outside, warning };

    this.label = document.createElement("div");
    this.label.className = "indicator__label";
    this.label.setAttribute("role", "status");
    this.label.setAttribute("aria-live", "polite");
    this.labelIcon = document.createElement("span");
    this.labelIcon.className = "indicator__icon";
    this.labelIcon.setAttribute("aria-hidden", "true");
    this.labelText = document.createElement("span");
    this.labelText.className = "indicator__text";
    this.label.append(this.labelIcon, this.labelText);
    this.sub = document.createElement("div");
    this.sub.className = "indicator__sub";
    if (opts.caption !== false) this.root.append(this.label, this.sub);
    parent.appendChild(this.root);
    this.update({ state: null, dx: null, dy: null, toleranceM: 0.1 });
  }

  update(inp: IndicatorInput): void {
    const key = stateKey(inp.state);
    if (key !== this.lastKey) {
      this.lastKey = key;
      this.root.dataset.state = key;
      const lab = LABELS[key];
      this.labelIcon.textContent = lab.icon;
      this.labelText.textContent = lab.title;
      for (const [k, g] of Object.entries(this.shapes)) {
        g.style.display = k === key ? "" : "none";
      }
      this.bg.setAttribute("class", `ind-bg ind-bg--${key}`);
    }
    let sub: string;
    const have = inp.dx !== null && inp.dy !== null && inp.state !== null;
    if (have) {
      const scale = R / Math.max(inp.toleranceM, 1e-3);
      let x = inp.dx! * scale;
      let y = -inp.dy! * scale; // forward (+y) is up on screen
      const r = Math.hypot(x, y);
      if (r > 88) {
        x *= 88 / r;
        y *= 88 / r;
      }
      const pos = `translate(${x.toFixed(1)} ${y.toFixed(1)})`;
      if (pos !== this.lastPos) {
        this.lastPos = pos;
        this.marker.setAttribute("transform", pos);
        this.trailPts.push([x, y]);
        if (this.trailPts.length > 40) this.trailPts.shift();
        this.trail.setAttribute(
          "points",
          this.trailPts.map(([a, b]) => `${a.toFixed(1)},${b.toFixed(1)}`).join(" "),
        );
      }
      this.marker.style.display = "";
      const cm = this.distance ? ` · ${(Math.hypot(inp.dx!, inp.dy!) * 100).toFixed(1)} cm` : "";
      sub =
        key === "ok"
          ? `Shoulder in place${cm}`
          : key === "outside"
            ? `Shoulder moved out${cm}`
            : `Shoulder out too long${cm}`;
    } else {
      this.marker.style.display = "none";
      if (this.trailPts.length) {
        this.trailPts = [];
        this.trail.setAttribute("points", "");
      }
      sub = inp.waitingText ?? "No shoulder estimate yet";
    }
    if (this.sub.textContent !== sub) this.sub.textContent = sub;
  }

  destroy(): void {
    this.root.remove();
  }
}
