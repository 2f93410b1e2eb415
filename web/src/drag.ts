// Coalescing of control-point edits while a point is dragged (as the Slicer module's
// ResectaLib/coalesce.py): at most one edit in flight; while one is, further positions are
// parked, one per control point, the latest replacing the earlier; when the edit in flight is
// answered the parked ones are sent, oldest point first. A group drag parks the whole grid under
// the key i = j = -1 and sends it as one `setControlPoints`. Each edit carries the newest plan
// version known; a stale-version answer (409 with `current_version`) re-bases and the position
// is sent again, unless a newer one for that point is parked. No DOM: testable in Node.

import { ApiError } from "./api";
import type { EditResponse, Vec3 } from "./api";

/** Control point P_ij of resection `name`; i = j = -1: all its points (a group drag). */
export interface ControlPointKey {
  name: string;
  i: number;
  j: number;
}

/** One point's position, or every point of the grid (row-major) for the key i = j = -1. */
export type DragValue = Vec3 | Vec3[];

/** Sends one `setControlPoint` (or `setControlPoints`) edit against `baseVersion`; resolves
 * with the server's answer. */
export type SendControlPoint = (key: ControlPointKey, point: DragValue, baseVersion: string) => Promise<EditResponse>;

interface Parked {
  key: ControlPointKey;
  point: DragValue;
  retries: number;
}

/** How often one position is sent again after stale-version answers before it is given up. */
const MAX_RETRIES = 3;

const keyOf = (k: ControlPointKey) => `${k.name}\u0000${k.i}\u0000${k.j}`;

export class DragCoalescer {
  private readonly parked = new Map<string, Parked>();
  private inFlight: Parked | null = null;
  private base = 0;
  /** The plan version of the last edit the server accepted (0: none yet). */
  acceptedVersion = 0;
  /** Counters, for tests and the status line. */
  readonly counts = { pushed: 0, sent: 0, replaced: 0, stale: 0, failed: 0 };
  /** Called after every answer (`error` when the edit failed for good) and when idle again. */
  onAnswer: (error: unknown | null) => void = () => {};
  onIdle: () => void = () => {};

  constructor(private readonly send: SendControlPoint) {}

  /** The plan version known to be current (from the watch stream); never goes back. */
  rebase(version: string | number): void {
    this.base = Math.max(this.base, Number(version) || 0);
  }

  get baseVersion(): string {
    return String(this.base);
  }

  get busy(): boolean {
    return this.inFlight !== null;
  }

  /** Whether edits of resection `name` are in flight or parked. */
  busyWith(name: string): boolean {
    if (this.inFlight?.key.name === name) return true;
    for (const p of this.parked.values()) if (p.key.name === name) return true;
    return false;
  }

  /** The position last pushed for each point of `name` not yet answered (parked or in flight). */
  pendingPoints(name: string): Map<string, Parked> {
    const out = new Map<string, Parked>();
    if (this.inFlight?.key.name === name) out.set(keyOf(this.inFlight.key), this.inFlight);
    for (const [k, p] of this.parked) if (p.key.name === name) out.set(k, p);
    return out;
  }

  /** A new position of a control point: sent now when idle, else parked. */
  push(key: ControlPointKey, point: DragValue): void {
    this.counts.pushed++;
    this.park({ key, point, retries: 0 });
    if (!this.inFlight) this.next();
  }

  /** Forgets the parked positions (e.g. before an undo). */
  clear(): void {
    this.parked.clear();
  }

  private park(p: Parked): void {
    const k = keyOf(p.key);
    if (this.parked.has(k)) this.counts.replaced++;
    this.parked.set(k, p); // an existing key keeps its place in the queue
  }

  private next(): void {
    const first = this.parked.entries().next();
    if (first.done) {
      this.onIdle();
      return;
    }
    const [k, p] = first.value;
    this.parked.delete(k);
    this.inFlight = p;
    this.counts.sent++;
    this.send(p.key, p.point, this.baseVersion).then(
      (answer) => this.answered(answer, null),
      (error: unknown) => this.answered(null, error),
    );
  }

  private answered(answer: EditResponse | null, error: unknown): void {
    const p = this.inFlight!;
    this.inFlight = null;
    if (answer) {
      this.rebase(answer.planVersion ?? 0);
      this.acceptedVersion = Math.max(this.acceptedVersion, Number(answer.planVersion ?? 0));
    } else if (error instanceof ApiError && error.status === 409 && error.problem.current_version !== undefined) {
      this.counts.stale++;
      this.rebase(error.problem.current_version);
      if (p.retries < MAX_RETRIES && !this.parked.has(keyOf(p.key))) this.park({ ...p, retries: p.retries + 1 });
      error = null;
    } else this.counts.failed++;
    this.onAnswer(answer ? null : error);
    this.next();
  }
}
