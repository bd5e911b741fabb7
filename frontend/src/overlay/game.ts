// The patient's game: collect the targets placed along the task's rectangular path with the
// hand (the robot's wrist cuff). The path is learnt from where the hand has been, so the game
// fits any task size. Pure logic (no DOM) so it can be reasoned about and tested alone.

export interface Rect {
  x0: number;
  x1: number;
  y0: number;
  y1: number;
}

export interface Target {
  x: number;
  y: number;
  collected: boolean;
}

function quantile(sorted: number[], q: number): number {
  const i = (sorted.length - 1) * q;
  const lo = Math.floor(i);
  const hi = Math.ceil(i);
  return sorted[lo]! + (sorted[hi]! - sorted[lo]!) * (i - lo);
}

/** The path's rectangle from hand positions (2nd–98th percentiles), or null if too small. */
export function learnRect(xs: number[], ys: number[], minSide = 0.05): Rect | null {
  if (xs.length < 50) return null;
  const sx = [...xs].sort((a, b) => a - b);
  const sy = [...ys].sort((a, b) => a - b);
  const r = { x0: quantile(sx, 0.02), x1: quantile(sx, 0.98), y0: quantile(sy, 0.02), y1: quantile(sy, 0.98) };
  if (r.x1 - r.x0 < minSide || r.y1 - r.y0 < minSide) return null;
  return r;
}

/** Eight targets: the corners and the middles of the edges, counter-clockwise from above. */
export function targetsOn(r: Rect): Target[] {
  const mx = (r.x0 + r.x1) / 2;
  const my = (r.y0 + r.y1) / 2;
  const pts: [number, number][] = [
    [r.x1, r.y1],
    [mx, r.y1],
    [r.x0, r.y1],
    [r.x0, my],
    [r.x0, r.y0],
    [mx, r.y0],
    [r.x1, r.y0],
    [r.x1, my],
  ];
  return pts.map(([x, y]) => ({ x, y, collected: false }));
}

export class Game {
  rect: Rect | null = null;
  targets: Target[] = [];
  score = 0;
  rounds = 0;
  paused = false;
  /** the hand must come this close to a target (metres) */
  radius = 0.03;
  private stable = 0;

  /** Update the path from the hand's recent positions; re-place targets when it moved. */
  learn(xs: number[], ys: number[]): void {
    const r = learnRect(xs.slice(-1500), ys.slice(-1500));
    if (!r) return;
    const old = this.rect;
    const moved =
      !old ||
      Math.abs(r.x0 - old.x0) + Math.abs(r.x1 - old.x1) + Math.abs(r.y0 - old.y0) + Math.abs(r.y1 - old.y1) >
        0.25 * Math.min(r.x1 - r.x0, r.y1 - r.y0);
    if (moved) {
      this.rect = r;
      this.radius = Math.max(0.02, 0.16 * Math.min(r.x1 - r.x0, r.y1 - r.y0));
      this.targets = targetsOn(r);
      this.stable = 0;
    } else {
      this.stable++;
    }
  }

  /** The hand is at (x, y): collect any target within reach. Returns how many were collected. */
  hand(x: number, y: number): number {
    if (this.paused || !this.targets.length) return 0;
    let got = 0;
    for (const t of this.targets) {
      if (!t.collected && Math.hypot(t.x - x, t.y - y) <= this.radius) {
        t.collected = true;
        got++;
      }
    }
    this.score += got;
    if (this.targets.every((t) => t.collected)) {
      this.rounds++;
      for (const t of this.targets) t.collected = false;
    }
    return got;
  }
}
