// Client of the server's public HTTP/JSON API (docs/server.md), same origin. Bodies are the
// protos' canonical JSON (64-bit integers as decimal strings, bytes as base64); errors are RFC
// 9457 problems. The watch stream is read with `fetch` (not EventSource, which cannot send the
// bearer token) and reconnects by itself, resuming from the last event id.

export interface Vec3 { x: number; y: number; z: number }
export interface Rgba { r?: number; g?: number; b?: number; a?: number }

export interface Session {
  id: string;
  displayName: string;
  createdMs?: string;
  lastAccessMs?: string;
  state?: string; // SESSION_STATE_*
  planVersion?: string;
  labelMap?: LabelMapSummary; // absent while SESSION_STATE_EMPTY
}

/** Label values per role (`RoleMap`); a role left out has none. */
export interface RoleMap {
  parenchyma?: number[];
  tumor?: number[];
  portal?: number[];
  hepatic?: number[];
  vessel?: number[];
}

export interface LabelMapSummary {
  dims?: number[];
  spacing?: number[];
  origin?: number[];
  direction?: number[];
  roles?: RoleMap;
  labels?: { label: number; voxels?: string; volumeMl?: number }[];
  liverVolumeMl?: number;
}

/** `FileLabelMapHeader` less the session and the length (the path and the body give them). */
export interface FileHeader {
  format: string; // LABEL_MAP_FORMAT_*
  roles?: RoleMap;
}

export interface ReconstructRequest {
  method?: string; // RECONSTRUCTION_METHOD_*
  options?: { psrDepth?: number; smoothing?: number; decimation?: number; splitComponents?: boolean; minComponentMm3?: number };
}

export interface ModelInfo {
  name: string;
  kind?: string;
  label?: number;
  triangleCount?: string;
  vertexCount?: string;
  volumeMl?: number;
  method?: string;
}

export interface ReconstructDone {
  modelCount?: number;
  elapsedS?: number;
  dropped?: { kind?: string; count?: number; volumeMl?: number }[];
  minComponentMm3?: number;
}

/** One event of a reconstruction (`ReconstructResponse`): exactly one field is set. */
export interface ReconstructEvent {
  progress?: { stage?: string; fraction?: number };
  model?: ModelInfo;
  done?: ReconstructDone;
}

/** `GetServerInfo`'s limits the page checks against (64-bit ones as decimal strings). */
export interface ServerLimits {
  maxUploadBytes?: string;
  minPsrDepth?: number;
  maxPsrDepth?: number;
}

export interface Resection {
  name: string;
  gridM?: number;
  gridN?: number;
  controlPoints?: Vec3[];
  marginMm?: number;
  bandMm?: number;
  ru?: number;
  rv?: number;
  kind?: ResectionKind; // absent: Bézier
  traces?: Trace[]; // DS and CP
  deformations?: Deformation[]; // CP
  target?: { labels?: number[]; points?: Vec3[] };
}

/** UNSPECIFIED is read as Bézier (the server never sends it). */
export type ResectionKind = "RESECTION_KIND_UNSPECIFIED" | "RESECTION_KIND_BEZIER" | "RESECTION_KIND_DS" | "RESECTION_KIND_CP";

/** A polyline drawn by the person (RAS mm). */
export interface Trace { points: Vec3[] }

/** A CP resection's local cosine bump along its plane's normal. */
export interface Deformation { point: Vec3; offsetMm?: number; radiusMm?: number }

export interface Verdict {
  minMarginMm?: number;
  point?: Vec3;
  violation?: boolean;
  violatingAreaMm2?: number;
  warningAreaMm2?: number;
  insideAreaMm2?: number;
  marginUncertaintyMm?: number;
}

export interface ResectionVolume {
  name: string;
  resectedMl?: number;
  resectedPct?: number;
  completeCut?: boolean;
  incompleteReason?: string;
  incompletePoint?: Partial<Vec3>;
  metrics?: ResectionMetrics;
}

/** Plan quality metrics of one resection (thesis Sec. 7.4). */
export interface ResectionMetrics {
  marginDeviationMm?: number;
  volumeDeviationPct?: number;
  medianAbsMeanCurvaturePerMm?: number;
}

export interface VolumeReport {
  totalMl?: number;
  remnantMl?: number;
  remnantPct?: number;
  resectedMl?: number;
  flrThresholdPct?: number;
  flrWarning?: boolean;
  complete?: boolean;
  resections?: ResectionVolume[];
  risk?: RiskReport; // when the label map has vessels and every cut is complete
  riskUnavailable?: string; // why there is no risk analysis although the roles name vessels
}

export type VesselSystem = "VESSEL_SYSTEM_PORTAL" | "VESSEL_SYSTEM_HEPATIC";

/** A vessel a resection cuts: where its centreline crosses the surface inside the liver. */
export interface CutVessel {
  system?: VesselSystem;
  resection?: string;
  branch?: number;
  generation?: number;
  radiusMm?: number;
  point?: Partial<Vec3>;
  u?: number; // on the resection's (u, v) square, 0..1
  v?: number;
  downstreamOfAnotherCut?: boolean;
}

/** What the cuts put at risk; `VolumeReport.flrWarning` then judges the functional remnant. */
export interface RiskReport {
  devascularisedMl?: number;
  congestedMl?: number;
  atRiskMl?: number;
  functionalRemnantMl?: number;
  functionalRemnantPct?: number;
  hasPortal?: boolean;
  hasHepatic?: boolean;
  cutVessels?: CutVessel[]; // largest radius first
}

/** `GetResectogramResponse`: pixel (r, c) shows the surface at u = (c + ½)/width, v = (r + ½)/height. */
export interface ResectogramResponse {
  planVersion?: string;
  resection?: string;
  width?: number;
  height?: number;
  classes?: string; // base64, one margin class per pixel, row-major
  territories?: number[]; // portal territory per pixel (0: none)
  cutVessels?: CutVessel[];
  worstU?: number;
  worstV?: number;
  minMarginMm?: number;
  marginMm?: number;
  bandMm?: number;
}

export interface Surface {
  name: string;
  kind?: string; // SURFACE_KIND_*
  label?: number;
  color?: Rgba;
  mesh?: string; // base64 RSMS
}

export interface ResectionSurface {
  name: string;
  resection?: Resection;
  verdict?: Verdict;
  fullMesh?: string; // base64 RSMS
  meshDelta?: string; // base64 RSDL
}

export interface Snapshot {
  session?: Session;
  models?: Surface[];
  resections?: ResectionSurface[];
  volumes?: VolumeReport;
  complete?: boolean;
}

export interface PlanDelta {
  resections?: ResectionSurface[];
  removed?: string[];
}

export interface WatchResponse {
  seq?: string;
  planVersion?: string;
  snapshot?: Snapshot;
  delta?: PlanDelta;
  volumes?: VolumeReport;
}

export type SliceAxis = "SLICE_AXIS_AXIAL" | "SLICE_AXIS_CORONAL" | "SLICE_AXIS_SAGITTAL";

/** `GetLabelSliceResponse`: pixel (r, c) centred at origin + c·pixelMm·columnAxis + r·pixelMm·rowAxis. */
export interface LabelSliceResponse {
  width?: number;
  height?: number;
  pixelMm?: number;
  origin?: Partial<Vec3>;
  columnAxis?: Partial<Vec3>;
  rowAxis?: Partial<Vec3>;
  labels?: string; // base64 of u16 little-endian, row-major
  minPositionMm?: number;
  maxPositionMm?: number;
}

export interface SlicePolyline {
  points?: string; // base64 of f32 little-endian x, y, z per point
  closed?: boolean;
}

export interface SlicesResponse {
  axial?: SlicePolyline[];
  coronal?: SlicePolyline[];
  sagittal?: SlicePolyline[];
}

export interface EditResponse {
  planVersion?: string;
  resections?: { resection?: Resection; verdict?: Verdict }[];
  removed?: string[];
}

/** One operation of `EditRequest` (its `edit` oneof), e.g. `{ setControlPoint: {...} }`. */
export type Edit = Record<string, unknown>;

export interface Problem {
  type?: string;
  title?: string;
  status?: number;
  detail?: string;
  code?: string;
  current_version?: string;
  replica?: ReplicaAddress; // SESSION_ELSEWHERE (421) only
}

/** Where a replicated server's replica is reached (a 421 `SESSION_ELSEWHERE` names the holder). */
export interface ReplicaAddress {
  id?: string;
  grpc_address?: string;
  http_url?: string;
  lease_remaining_ms?: number;
}

/** Called once when the session is held by another replica (421 with its `http_url`): the page
 * cannot call that origin (same-origin CSP, no CORS), so it moves there. `pageUrl` is the other
 * replica's page opening the session (`<http_url>/#session=<id>`). */
export type OnElsewhere = (pageUrl: string, replica: ReplicaAddress, sessionId: string | null) => void;

/** The other replica's page that opens `sessionId` (`#session=<id>`, read by the page at start). */
export function replicaPageUrl(httpUrl: string, sessionId: string | null): string {
  const base = `${httpUrl.replace(/\/+$/, "")}/`;
  return sessionId ? `${base}#session=${encodeURIComponent(sessionId)}` : base;
}

/** The session of a page's `#session=<id>` fragment (`location.hash`), or null. */
export function sessionFromHash(hash: string): string | null {
  const id = new URLSearchParams(hash.replace(/^#/, "")).get("session");
  return id || null;
}

/** The holder's HTTP base URL when `e` is a 421 SESSION_ELSEWHERE naming one, else null. */
export function elsewhereUrl(e: unknown): string | null {
  if (!(e instanceof ApiError) || e.status !== 421) return null;
  return e.problem.replica?.http_url || null;
}

/** The session named by an API path (`/v1/sessions/<id>/...`), or null. */
function sessionOf(path: string): string | null {
  const m = /^\/v1\/sessions\/([^/?]+)/.exec(path);
  return m ? decodeURIComponent(m[1]!) : null;
}

/** 421 SESSION_ELSEWHERE without a replica (the session is moving): tries, and the wait before each. */
const ELSEWHERE_RETRIES = 8;
const ELSEWHERE_DELAY_MS = 250;

/** An HTTP error answer (or a stream's `error` event), with its problem when it sent one. */
export class ApiError extends Error {
  override name = "ApiError";
  constructor(
    readonly status: number,
    readonly problem: Problem,
  ) {
    super(`${status} ${problem.code ?? problem.title ?? ""}: ${problem.detail ?? ""}`.trim());
  }
}

/** What went wrong, for people: a problem's text (its detail, else its title), else the message. */
export function problemText(e: unknown): string {
  if (e instanceof ApiError) return e.problem.detail || e.problem.title || e.message;
  return e instanceof Error ? e.message : String(e);
}

const TOKEN_KEY = "resecta.token";
/** The decoder (wire.ts) reads compressed and quantised meshes: a server may send them. */
const WATCH_QUERY = "allowZstd=true&allowQuantized=true";

/** Asks the person for the bearer token (null: they declined). */
export type AskToken = (retry: boolean) => Promise<string | null>;

export class Api {
  private asking: Promise<string | null> | null = null;
  private moving = false;
  /** Set by the page: how it moves to the replica holding the session (see `OnElsewhere`). */
  onElsewhere: OnElsewhere | null = null;

  /** `base`: the server's origin ("" on the page: same origin); `tokens`: where the token is
   * kept (the tab's sessionStorage). */
  constructor(
    private readonly askToken: AskToken,
    private readonly base = "",
    private readonly tokens: Pick<Storage, "getItem" | "setItem"> = sessionStorage,
  ) {}

  listSessions(): Promise<{ sessions?: Session[] }> {
    return this.json("GET", "/v1/sessions");
  }
  createSession(displayName: string): Promise<{ session: Session }> {
    return this.json("POST", "/v1/sessions", { displayName });
  }
  getSession(id: string): Promise<{ session: Session }> {
    return this.json("GET", `/v1/sessions/${enc(id)}`);
  }
  info(): Promise<{ serverVersion?: string; capabilities?: string[]; limits?: ServerLimits }> {
    return this.json("GET", "/v1/info");
  }
  /** Uploads a label-map file (`UploadLabelMap`) with XMLHttpRequest, which, unlike `fetch`,
   * reports the upload's progress; the token as `fetch` sends it, asked for on a 401. */
  async uploadLabelMap(
    id: string,
    file: Blob,
    header: FileHeader,
    onProgress: (sent: number, total: number) => void,
  ): Promise<{ labelMap?: LabelMapSummary }> {
    const url = `${this.base}/v1/sessions/${enc(id)}/label-map?file=${enc(JSON.stringify(header))}`;
    let misdirected = 0;
    for (let retry = false; ; retry = true) {
      const { headers, token } = this.headers({ "content-type": "application/octet-stream" });
      const xhr = new XMLHttpRequest();
      const loaded = new Promise<void>((resolve, reject) => {
        xhr.upload.onprogress = (e) => onProgress(e.loaded, e.lengthComputable ? e.total : file.size);
        xhr.onload = () => resolve();
        xhr.onerror = () => reject(new TypeError("the upload failed (network error)"));
      });
      xhr.open("PUT", url);
      for (const [k, v] of Object.entries(headers)) xhr.setRequestHeader(k, v);
      xhr.send(file);
      await loaded;
      if (xhr.status >= 200 && xhr.status < 300) return JSON.parse(xhr.responseText) as { labelMap?: LabelMapSummary };
      const problem = problemOf(xhr.status, xhr.statusText, xhr.responseText);
      if (xhr.status === 421 && (await this.misdirected(problem, id, ++misdirected))) continue;
      if (xhr.status !== 401) throw new ApiError(xhr.status, problem);
      await this.renewToken(token, retry, problem);
    }
  }
  /** Builds the models (`Reconstruct`): its events as they come, until `done`. Aborting
   * `signal` closes the request, and the server cancels the reconstruction. */
  async *reconstruct(id: string, req: ReconstructRequest, signal?: AbortSignal): AsyncGenerator<ReconstructEvent> {
    const res = await this.fetch("POST", `/v1/sessions/${enc(id)}/reconstruct`, JSON.stringify(req), {
      "content-type": "application/json",
      accept: "text/event-stream",
    }, signal);
    for await (const ev of sseEvents(res.body!)) {
      const data = JSON.parse(ev.data) as unknown;
      if (ev.event === "error") throw new ApiError((data as Problem).status ?? 500, data as Problem);
      yield data as ReconstructEvent;
      if ((data as ReconstructEvent).done) return;
    }
    throw new ApiError(502, { title: "The reconstruction stream ended before its done event" });
  }
  /** Applies one edit made against `baseVersion` (0: unchecked; a stale one gets a 409). */
  edit(id: string, baseVersion: string | number, edit: Edit): Promise<EditResponse> {
    return this.json("POST", `/v1/sessions/${enc(id)}/edits`, { baseVersion: String(baseVersion), ...edit });
  }
  exportPlan(id: string): Promise<{ planVersion?: string; planJson: string }> {
    return this.json("GET", `/v1/sessions/${enc(id)}/plan`);
  }
  /** Replaces the plan with a `resecta-plan/1` document, checked against `baseVersion`. */
  importPlan(id: string, planJson: string, baseVersion: string | number): Promise<{ planVersion?: string }> {
    return this.json("PUT", `/v1/sessions/${enc(id)}/plan`, { planJson, baseVersion: String(baseVersion) });
  }
  /** A model's or a resection's mesh file (`format`: MODEL_FORMAT_VTP, _STL, _PLY, _OBJ, _VTK). */
  async exportModel(id: string, name: string, format: string): Promise<Blob> {
    const res = await this.fetch("GET", `/v1/sessions/${enc(id)}/models/${enc(name)}?format=${enc(format)}`, undefined, {});
    return res.blob();
  }
  volumes(id: string): Promise<{ planVersion?: string; volumes?: VolumeReport }> {
    return this.json("GET", `/v1/sessions/${enc(id)}/volumes`);
  }
  /** Resection `resection` unrolled to its (u, v) square, `width` × `height` pixels. */
  resectogram(id: string, resection: string, width: number, height: number): Promise<ResectogramResponse> {
    const q = new URLSearchParams({ resection, width: String(width), height: String(height) });
    return this.json("GET", `/v1/sessions/${enc(id)}/resectogram?${q}`);
  }
  /** One plane of the label map as a raster (`pixelMm` absent: the finest voxel spacing). */
  labelSlice(id: string, axis: SliceAxis, positionMm: number, pixelMm?: number): Promise<LabelSliceResponse> {
    const q = new URLSearchParams({ axis, positionMm: String(positionMm) });
    if (pixelMm !== undefined) q.set("pixelMm", String(pixelMm));
    return this.json("GET", `/v1/sessions/${enc(id)}/label-slice?${q}`);
  }
  /** A resection's contours on the planes given (RAS z, y, x mm). */
  slices(id: string, resection: string, at: { axial?: number; coronal?: number; sagittal?: number }): Promise<SlicesResponse> {
    const q = new URLSearchParams({ resection });
    for (const [k, v] of Object.entries(at)) if (v !== undefined) q.set(k, String(v));
    return this.json("GET", `/v1/sessions/${enc(id)}/slices?${q}`);
  }

  /** Follows a session's watch stream until `close()`: whole snapshots (parts joined), deltas
   * and volumes, in order. Reconnects after a network error, a server shutdown (503), a 421
   * without a replica (the session is moving) or the stream's end, resuming after the last
   * event seen; `resync()` drops that and asks for a fresh snapshot (after a delta that did not
   * apply). A 421 naming the replica that holds the session (as the answer or as the stream's
   * error event) ends the stream (`failed`) after `onElsewhere` was called: the page moves. */
  watch(id: string, on: WatchHandlers): WatchStream {
    let lastSeq: string | null = null;
    let abort = new AbortController();
    let closed = false;
    const run = async () => {
      for (let attempt = 0; !closed; attempt++) {
        let parts: Snapshot[] = [];
        try {
          const headers: Record<string, string> = { accept: "text/event-stream" };
          if (lastSeq !== null) headers["last-event-id"] = lastSeq;
          const res = await this.fetch("GET", `/v1/sessions/${enc(id)}/watch?${WATCH_QUERY}`, undefined, headers, abort.signal);
          on.status("live");
          for await (const ev of sseEvents(res.body!)) {
            attempt = 0;
            const received = performance.now();
            const data = JSON.parse(ev.data) as unknown;
            if (ev.event === "error") throw new ApiError((data as Problem).status ?? 500, data as Problem);
            const msg = data as WatchResponse;
            if (msg.snapshot) {
              parts.push(msg.snapshot);
              if (!msg.snapshot.complete) continue;
              on.snapshot(joinParts(parts), msg);
              parts = [];
            } else if (msg.delta) on.delta(msg.delta, msg, received);
            else if (msg.volumes) on.volumes(msg.volumes, msg);
            if (abort.signal.aborted) break; // close() or resync() from a handler
            if (ev.id) lastSeq = ev.id;
          }
          if (closed) return;
          if (abort.signal.aborted) abort = new AbortController();
          else on.status("reconnecting", null);
        } catch (e) {
          if (closed) return;
          if (abort.signal.aborted) abort = new AbortController(); // resync
          else if (e instanceof ApiError && e.status === 421) {
            if (elsewhereUrl(e)) {
              this.elsewhere(e.problem, id);
              on.status("failed", e);
              return;
            }
            on.status("reconnecting", e); // no replica named: the session is moving, ask again
          } else if (e instanceof ApiError && e.status !== 503) {
            on.status("failed", e);
            return;
          } else on.status("reconnecting", e);
        }
        await sleep(Math.min(10_000, 500 * 2 ** Math.min(attempt, 5)));
      }
    };
    void run();
    return {
      close() {
        closed = true;
        abort.abort();
      },
      resync() {
        lastSeq = null;
        abort.abort();
      },
    };
  }

  private async json<T>(method: string, path: string, body?: unknown): Promise<T> {
    const res = await this.fetch(method, path, body === undefined ? undefined : JSON.stringify(body), {
      "content-type": "application/json",
    });
    return (await res.json()) as T;
  }

  /** `fetch` with the token; on a 401 asks for the token (once at a time) and tries again; on a
   * 421 SESSION_ELSEWHERE moves the page to the replica named (`onElsewhere`) and throws, or,
   * without one, tries again after a short wait. */
  private async fetch(
    method: string,
    path: string,
    body: string | undefined,
    extra: Record<string, string>,
    signal?: AbortSignal,
  ): Promise<Response> {
    let misdirected = 0;
    for (let retry = false; ; retry = true) {
      const { headers, token } = this.headers(extra);
      const init: RequestInit = { method, headers };
      if (body !== undefined) init.body = body;
      if (signal) init.signal = signal;
      const res = await fetch(this.base + path, init);
      if (res.ok) return res;
      const problem = problemOf(res.status, res.statusText, await res.text().catch(() => ""));
      if (res.status === 421 && (await this.misdirected(problem, sessionOf(path), ++misdirected))) continue;
      if (res.status !== 401) throw new ApiError(res.status, problem);
      await this.renewToken(token, retry, problem);
    }
  }

  /** After a 421 (the `n`th in a row): true to try again (no replica named: the session is
   * moving; after a short wait, a few times), false to throw it, after handing a named replica
   * to `onElsewhere`. */
  private async misdirected(problem: Problem, sessionId: string | null, n: number): Promise<boolean> {
    if (problem.replica?.http_url) {
      this.elsewhere(problem, sessionId);
      return false;
    }
    if (n > ELSEWHERE_RETRIES) return false;
    await sleep(ELSEWHERE_DELAY_MS * n);
    return true;
  }

  /** Hands the replica holding the session to `onElsewhere`, once. */
  private elsewhere(problem: Problem, sessionId: string | null): void {
    const replica = problem.replica;
    if (!replica?.http_url || this.moving || !this.onElsewhere) return;
    this.moving = true;
    this.onElsewhere(replicaPageUrl(replica.http_url, sessionId), replica, sessionId);
  }

  /** A request's headers: the API version, the token kept (if any) and `extra`. */
  private headers(extra: Record<string, string>): { headers: Record<string, string>; token: string | null } {
    const token = this.tokens.getItem(TOKEN_KEY);
    const headers: Record<string, string> = { "resecta-api-version": "v1", ...extra };
    if (token) headers["authorization"] = `Bearer ${token}`;
    return { headers, token };
  }

  /** After a 401 to a request sent with `token`: asks for the token (once at a time) and keeps
   * it; throws the 401 when the person declines. */
  private async renewToken(token: string | null, retry: boolean, problem: Problem): Promise<void> {
    this.asking ??= this.askToken(token !== null || retry).finally(() => (this.asking = null));
    const given = await this.asking;
    if (!given) throw new ApiError(401, problem);
    this.tokens.setItem(TOKEN_KEY, given);
  }
}

export interface WatchHandlers {
  snapshot(s: Snapshot, msg: WatchResponse): void;
  /** `received`: `performance.now()` when its event came, before its JSON was parsed. */
  delta(d: PlanDelta, msg: WatchResponse, received: number): void;
  volumes(v: VolumeReport, msg: WatchResponse): void;
  /** The connection: live, reconnecting (with what went wrong, if anything) or failed for good. */
  status(s: "live" | "reconnecting" | "failed", error?: unknown): void;
}

export interface WatchStream {
  close(): void;
  resync(): void;
}

/** A snapshot's parts as one snapshot (session from the first, volumes from the last). */
export function joinParts(parts: Snapshot[]): Snapshot {
  const out: Snapshot = { models: [], resections: [], complete: true };
  for (const p of parts) {
    out.session ??= p.session;
    out.models!.push(...(p.models ?? []));
    out.resections!.push(...(p.resections ?? []));
    if (p.volumes) out.volumes = p.volumes;
  }
  return out;
}

export interface SseEvent { event: string; id: string | null; data: string }

/** The server-sent events of a byte stream (the WHATWG event-stream format). */
export async function* sseEvents(body: ReadableStream<Uint8Array>): AsyncGenerator<SseEvent> {
  const reader = body.getReader();
  const text = new TextDecoder();
  let buf = "";
  let from = 0; // buf before this has no line break
  let event = "message", id: string | null = null, data: string[] = [];
  const lineBreak = /\r\n|\r|\n/g;
  try {
    for (;;) {
      const { value, done } = await reader.read();
      if (done) return;
      buf += text.decode(value, { stream: true });
      for (;;) {
        lineBreak.lastIndex = from;
        const m = lineBreak.exec(buf);
        // A CR at the end may be the first half of a CRLF: wait for the next chunk.
        if (!m || (m[0] === "\r" && m.index === buf.length - 1)) {
          from = m ? m.index : buf.length;
          break;
        }
        const line = buf.slice(0, m.index);
        buf = buf.slice(m.index + m[0].length);
        from = 0;
        if (line === "") {
          if (data.length) yield { event, id, data: data.join("\n") };
          event = "message";
          data = [];
          continue;
        }
        const colon = line.indexOf(":");
        if (colon === 0) continue; // comment
        const field = colon < 0 ? line : line.slice(0, colon);
        const value = colon < 0 ? "" : line.slice(colon + (line[colon + 1] === " " ? 2 : 1));
        if (field === "event") event = value;
        else if (field === "data") data.push(value);
        else if (field === "id") id = value;
      }
    }
  } finally {
    reader.releaseLock();
  }
}

/** Bytes of a base64 string (mesh bytes in the JSON). */
export function base64Bytes(b64: string): Uint8Array {
  const bin = atob(b64);
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}

/** The problem of an error answer's body (or one made of its status when it is not JSON). */
function problemOf(status: number, statusText: string, text: string): Problem {
  try {
    return JSON.parse(text) as Problem;
  } catch {
    return { status, title: statusText, detail: text.slice(0, 200) };
  }
}

const enc = encodeURIComponent;
const sleep = (ms: number) => new Promise((r) => setTimeout(r, ms));
