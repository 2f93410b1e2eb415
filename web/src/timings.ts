// Delta → repainted frame, measured in the page (issue #20's performance item). For each delta of
// the watch stream: when its event was received, when the plan and the scene's meshes had applied
// it, when the scene rendered it and the next animation frame after that render (the frame that
// shows it). The last `keep` are kept in memory for `window.resecta.timings()`; nothing is logged.
// Times are `performance.now()` (add `performance.timeOrigin` for the epoch).

export interface Timings {
  /** The plan version each delta carried. */
  planVersion: number[];
  /** When its watch event was received (before its JSON was parsed). */
  arrivalAt: number[];
  /** When the next animation frame after its render ran. */
  paintAt: number[];
  /** Received → decoded and applied to the plan and the scene's meshes. */
  arrivalToApplyMs: number[];
  /** Received → `scene.render()` done. */
  arrivalToRenderMs: number[];
  /** Received → the next animation frame after that render. */
  arrivalToPaintMs: number[];
}

interface Entry { planVersion: number; arrivalAt: number; applyAt: number; renderAt: number; paintAt: number }

export class RepaintTimer {
  private readonly done: Entry[] = [];
  private applied: Entry[] = [];
  private rendered: Entry[] = [];

  constructor(private readonly keep = 256) {}

  /** A delta received at `arrivalAt` has been applied (`now`); the next render shows it. */
  apply(planVersion: number, arrivalAt: number, now: number): void {
    this.applied.push({ planVersion, arrivalAt, applyAt: now, renderAt: NaN, paintAt: NaN });
  }

  /** The scene has rendered; true if deltas now wait for the next frame (then call `paint`). */
  render(now: number): boolean {
    for (const e of this.applied) e.renderAt = now;
    this.rendered.push(...this.applied);
    this.applied = [];
    return this.rendered.length > 0;
  }

  /** The animation frame after the render. */
  paint(now: number): void {
    for (const e of this.rendered) e.paintAt = now;
    this.done.push(...this.rendered);
    this.rendered = [];
    if (this.done.length > this.keep) this.done.splice(0, this.done.length - this.keep);
  }

  timings(): Timings {
    const col = (f: (e: Entry) => number) => this.done.map(f);
    return {
      planVersion: col((e) => e.planVersion),
      arrivalAt: col((e) => e.arrivalAt),
      paintAt: col((e) => e.paintAt),
      arrivalToApplyMs: col((e) => e.applyAt - e.arrivalAt),
      arrivalToRenderMs: col((e) => e.renderAt - e.arrivalAt),
      arrivalToPaintMs: col((e) => e.paintAt - e.arrivalAt),
    };
  }
}
