// uPlot helpers: shared styling, a tolerance band, relative-time axes, resize handling.

import uPlot from "uplot";
import type { AlignedData, Options, Series, Axis } from "uplot";

export const INK = "#1f2933";
export const GRID = "#e5e7eb";
export const BAND = "rgba(0, 158, 115, 0.12)";
export const LINE = {
  disp: "#0072B2",
  elbow: "#CC79A7",
  elev: "#D55E00",
  azim: "#56B4E9",
  tol: "#6b7280",
  comp: "#E69F00",
  ok: "#009E73",
};

export interface ChartSpec {
  title: string;
  yLabel: string;
  series: { label: string; color: string; dash?: number[]; width?: number; points?: boolean }[];
  /** fixed y range or a minimum span */
  yRange?: [number, number];
  yMin?: number;
  /** shade y in [0, band()] (the tolerance) */
  band?: () => number | null;
  /** x axis: "relative" (seconds before the latest sample), "seconds", or "index" labels */
  x?: "relative" | "seconds" | "sessions";
  xLabels?: () => string[];
  height?: number;
}

function bandPlugin(band: () => number | null): uPlot.Plugin {
  return {
    hooks: {
      drawClear: (u: uPlot) => {
        const b = band();
        if (b === null || !Number.isFinite(b)) return;
        const { ctx } = u;
        const y0 = u.valToPos(0, "y", true);
        const y1 = u.valToPos(b, "y", true);
        ctx.save();
        ctx.fillStyle = BAND;
        ctx.fillRect(u.bbox.left, Math.min(y0, y1), u.bbox.width, Math.abs(y0 - y1));
        ctx.restore();
      },
    },
  };
}

export function makeOptions(spec: ChartSpec, width: number): Options {
  const x = spec.x ?? "relative";
  const axisBase: Partial<Axis> = {
    stroke: INK,
    grid: { stroke: GRID, width: 1 },
    ticks: { stroke: GRID, width: 1 },
    font: "13px system-ui, sans-serif",
    labelFont: "13px system-ui, sans-serif",
  };
  const xAxis: Axis = { ...axisBase };
  if (x === "relative") {
    xAxis.values = (u, splits) => {
      const xs = u.data[0];
      const last = xs.length ? xs[xs.length - 1]! : 0;
      return splits.map((s) => {
        const d = Math.round(s - last);
        return d === 0 ? "now" : `${d} s`;
      });
    };
  } else if (x === "seconds") {
    xAxis.values = (_u, splits) => splits.map((s) => fmtClock(s));
    xAxis.label = "session time";
  } else {
    const labels = spec.xLabels ?? (() => []);
    xAxis.values = (_u, splits) => splits.map((s) => (Number.isInteger(s) ? labels()[s] ?? "" : ""));
    xAxis.space = 60;
  }
  const series: Series[] = [{ label: x === "sessions" ? "Session" : "t" }];
  for (const s of spec.series) {
    series.push({
      label: s.label,
      stroke: s.color,
      width: s.width ?? 2,
      dash: s.dash,
      spanGaps: false,
      points: s.points ? { show: true, size: 8, fill: s.color } : { show: false },
    });
  }
  const yRange: uPlot.Scale["range"] = spec.yRange
    ? spec.yRange
    : (_u, lo, hi) => {
        const min = spec.yMin !== undefined ? Math.min(spec.yMin, lo) : lo;
        const span = Math.max(hi - min, 1);
        return [min === spec.yMin ? min : min - span * 0.05, hi + span * 0.08];
      };
  return {
    width,
    height: spec.height ?? 180,
    title: undefined,
    legend: { show: true, live: false },
    cursor: { drag: { x: false, y: false }, points: { show: false } },
    scales: { x: { time: false }, y: { range: yRange } },
    axes: [xAxis, { ...axisBase, label: spec.yLabel, size: 56 }],
    series,
    plugins: spec.band ? [bandPlugin(spec.band)] : [],
  };
}

export function fmtClock(s: number): string {
  if (!Number.isFinite(s)) return "";
  const m = Math.floor(s / 60);
  const r = Math.round(s - m * 60);
  return `${m}:${String(r).padStart(2, "0")}`;
}

/** A uPlot instance that follows its container's width. */
export class Chart {
  readonly u: uPlot;
  private ro: ResizeObserver;

  constructor(container: HTMLElement, spec: ChartSpec, data: AlignedData) {
    const w = Math.max(container.clientWidth, 200);
    this.u = new uPlot(makeOptions(spec, w), data, container);
    this.ro = new ResizeObserver(() => {
      const cw = Math.max(container.clientWidth, 200);
      if (Math.abs(cw - this.u.width) > 2) this.u.setSize({ width: cw, height: this.u.height });
    });
    this.ro.observe(container);
  }

  /** New data; with ``xRange`` the x scale is pinned (a sliding live window). One redraw. */
  setData(data: AlignedData, xRange?: [number, number]): void {
    this.u.batch(() => {
      this.u.setData(data, true);
      if (xRange) this.u.setScale("x", { min: xRange[0], max: xRange[1] });
    });
  }

  destroy(): void {
    this.ro.disconnect();
    this.u.destroy();
  }
}
