// The 3D view (vtk.js): one actor per surface, models in their structure's colour and opacity,
// resection surfaces coloured per vertex by margin class. The actors share the decoded meshes'
// arrays, so a delta applied in place needs only `update(name)` and a render.

import "@kitware/vtk.js/Rendering/OpenGL/Profiles/Geometry"; // WebGL only: smaller than with WebGPU
import vtkDataArray from "@kitware/vtk.js/Common/Core/DataArray";
import vtkPolyData from "@kitware/vtk.js/Common/DataModel/PolyData";
import vtkSphereSource from "@kitware/vtk.js/Filters/Sources/SphereSource";
import vtkInteractorStyleTrackballCamera from "@kitware/vtk.js/Interaction/Style/InteractorStyleTrackballCamera";
import vtkActor from "@kitware/vtk.js/Rendering/Core/Actor";
import vtkCellPicker from "@kitware/vtk.js/Rendering/Core/CellPicker";
import vtkMapper from "@kitware/vtk.js/Rendering/Core/Mapper";
import { ColorMode, ScalarMode } from "@kitware/vtk.js/Rendering/Core/Mapper/Constants";
import vtkRenderer from "@kitware/vtk.js/Rendering/Core/Renderer";
import vtkRenderWindow from "@kitware/vtk.js/Rendering/Core/RenderWindow";
import vtkRenderWindowInteractor from "@kitware/vtk.js/Rendering/Core/RenderWindowInteractor";
import vtkOpenGLRenderWindow from "@kitware/vtk.js/Rendering/OpenGL/RenderWindow";
import type { CutVessel, Vec3 } from "./api";
import { CUT_VESSEL_RGB, MARGIN_CLASS_RGBA } from "./colours";
import type { Mesh } from "./wire";

type Rgb = [number, number, number];

/** Colour and opacity per surface kind (the Slicer module's palette, ResectaLib/models.py). */
export const PALETTE: Record<string, [Rgb, number]> = {
  parenchyma: [[0.867, 0.51, 0.396], 0.35],
  tumor: [[0.306, 0.706, 0.306], 1.0],
  portal: [[0.788, 0.373, 0.733], 1.0],
  hepatic: [[0.0, 0.592, 0.808], 1.0],
  vessel: [[0.847, 0.396, 0.31], 1.0],
  resection: [[0.75, 0.75, 0.75], 1.0],
};

export interface SurfaceStyle {
  kind: string; // parenchyma, tumor, ..., resection
  rgb?: Rgb; // the server's suggestion, else the palette's
  opacity?: number;
}

/** The control grid's colour (spheres and lines). */
const GRID_RGB: Rgb = [1.0, 0.78, 0.1];
/** The closest point's marker. */
const MARKER_RGB: Rgb = [1.0, 0.1, 0.6];
/** Traces of DS and CP resections (the slice view's trace colour). */
const TRACE_RGB: Rgb = [0.29, 0.85, 1.0];

/** A point on the page: client (CSS) pixels, and the normalised depth there (0 near, 1 far). */
export interface ScreenPoint {
  x: number;
  y: number;
  depth: number;
}

type PolyData = ReturnType<typeof vtkPolyData.newInstance>;

interface Entry {
  mesh: Mesh;
  polyData: ReturnType<typeof vtkPolyData.newInstance>;
  actor: ReturnType<typeof vtkActor.newInstance>;
  colors: Uint8Array | null; // per-vertex RGBA of margin classes
}

export class Scene {
  private readonly renderer = vtkRenderer.newInstance({ background: [0.1, 0.11, 0.13] });
  private readonly renderWindow = vtkRenderWindow.newInstance();
  private readonly entries = new Map<string, Entry>();
  private framed = false;
  private readonly gl = vtkOpenGLRenderWindow.newInstance();
  private readonly spheres = gridActor(2);
  private readonly lines = gridActor(2);
  private readonly marker = gridActor(1, MARKER_RGB);
  private readonly traceLines = gridActor(3, TRACE_RGB);
  private readonly tracePoints = gridActor(1, TRACE_RGB);
  private readonly cutVessels = {
    VESSEL_SYSTEM_PORTAL: gridActor(1, CUT_VESSEL_RGB.VESSEL_SYSTEM_PORTAL),
    VESSEL_SYSTEM_HEPATIC: gridActor(1, CUT_VESSEL_RGB.VESSEL_SYSTEM_HEPATIC),
  };
  private readonly picker = vtkCellPicker.newInstance({ tolerance: 0 });
  /** Opacity and visibility the person set per surface name; kept across snapshots. */
  private readonly looks = new Map<string, { opacity?: number; visible?: boolean }>();

  /** A render window filling `container` (vtk.js's FullScreenRenderWindow, WebGL only). */
  constructor(container: HTMLElement) {
    this.renderWindow.addRenderer(this.renderer);
    const gl = this.gl;
    gl.setContainer(container);
    this.renderWindow.addView(gl);
    const interactor = vtkRenderWindowInteractor.newInstance();
    interactor.setView(gl);
    interactor.initialize();
    interactor.bindEvents(container);
    interactor.setInteractorStyle(vtkInteractorStyleTrackballCamera.newInstance());
    new ResizeObserver(() => {
      const { width, height } = container.getBoundingClientRect();
      const dpr = window.devicePixelRatio || 1;
      gl.setSize(Math.floor(width * dpr), Math.floor(height * dpr));
      this.renderWindow.render();
    }).observe(container);
  }

  names(): string[] {
    return [...this.entries.keys()];
  }

  /** Shows `mesh` as `name`: a mesh already shown was changed in place and is updated, another
   * replaces what was there. */
  show(name: string, mesh: Mesh, style: SurfaceStyle): void {
    if (this.entries.get(name)?.mesh === mesh) this.update(name);
    else this.set(name, mesh, style);
  }

  /** Shows `mesh` as `name`, replacing what was there. */
  set(name: string, mesh: Mesh, style: SurfaceStyle): void {
    this.remove(name);
    const polyData = vtkPolyData.newInstance();
    polyData.getPoints().setData(mesh.positions, 3);
    const cells = new Uint32Array(4 * (mesh.triangles.length / 3));
    for (let t = 0, c = 0; t < mesh.triangles.length; t += 3, c += 4) {
      cells[c] = 3;
      cells.set(mesh.triangles.subarray(t, t + 3), c + 1);
    }
    polyData.getPolys().setData(cells);
    if (mesh.normals) {
      polyData.getPointData().setNormals(vtkDataArray.newInstance({ name: "Normals", numberOfComponents: 3, values: mesh.normals }));
    }
    const colors = mesh.classes ? new Uint8Array(4 * mesh.vertexCount) : null;
    if (colors) {
      polyData.getPointData().setScalars(vtkDataArray.newInstance({ name: "margin_class", numberOfComponents: 4, values: colors }));
    }
    const mapper = vtkMapper.newInstance({ interpolateScalarsBeforeMapping: false });
    mapper.setInputData(polyData);
    if (colors) {
      mapper.setColorMode(ColorMode.DIRECT_SCALARS);
      mapper.setScalarMode(ScalarMode.USE_POINT_DATA);
    } else mapper.setScalarVisibility(false);
    const actor = vtkActor.newInstance();
    actor.setMapper(mapper);
    const [rgb, opacity] = PALETTE[style.kind] ?? PALETTE["vessel"]!;
    actor.getProperty().setColor(...(style.rgb ?? rgb));
    actor.getProperty().setOpacity(style.opacity ?? opacity);
    if (colors) actor.setForceTranslucent(true);
    const look = this.looks.get(name);
    if (look?.opacity !== undefined) actor.getProperty().setOpacity(look.opacity);
    if (look?.visible !== undefined) actor.setVisibility(look.visible);
    const entry: Entry = { mesh, polyData, actor, colors };
    this.entries.set(name, entry);
    this.paintClasses(entry);
    this.renderer.addActor(actor);
  }

  /** After `name`'s mesh arrays changed in place (a delta applied). */
  update(name: string): void {
    const e = this.entries.get(name);
    if (!e) return;
    this.paintClasses(e);
    e.polyData.getPoints().modified();
    e.polyData.getPointData().getNormals()?.modified();
    e.polyData.modified();
  }

  remove(name: string): void {
    const e = this.entries.get(name);
    if (!e) return;
    this.renderer.removeActor(e.actor);
    e.actor.getMapper()?.delete();
    e.actor.delete();
    e.polyData.delete();
    this.entries.delete(name);
  }

  clear(): void {
    for (const name of this.names()) this.remove(name);
  }

  /** The opacity (0..1) and visibility of surface `name`, now and after it is replaced. */
  setLook(name: string, look: { opacity?: number; visible?: boolean }): void {
    const kept = { ...this.looks.get(name), ...look };
    this.looks.set(name, kept);
    const actor = this.entries.get(name)?.actor;
    if (kept.opacity !== undefined) actor?.getProperty().setOpacity(kept.opacity);
    if (kept.visible !== undefined) actor?.setVisibility(kept.visible);
  }

  /** The opacity and visibility surface `name` is drawn with. */
  look(name: string): { opacity: number; visible: boolean } | null {
    const actor = this.entries.get(name)?.actor;
    return actor ? { opacity: actor.getProperty().getOpacity(), visible: actor.getVisibility() } : null;
  }

  /** Marks `p` (a resection's closest point to its tumour) with a red sphere; null hides it. */
  mark(p: Vec3 | null, radius = 2): void {
    const shown = this.renderer.hasViewProp(this.marker.actor);
    if (!p) {
      if (shown) this.renderer.removeActor(this.marker.actor);
      return;
    }
    setSpheres(this.marker.polyData, [p], radius);
    if (!shown) this.renderer.addActor(this.marker.actor);
  }

  /** Marks each cut vessel with a sphere at its crossing, blue (portal) or purple (hepatic),
   * replacing those marked before; its radius max(2, 1.5 × the vessel's) mm, so that it shows
   * around the vessel's own surface. */
  showCutVessels(vessels: readonly CutVessel[]): void {
    for (const [system, g] of Object.entries(this.cutVessels)) {
      const these = vessels.filter((c) => c.system === system && c.point);
      const shown = this.renderer.hasViewProp(g.actor);
      if (!these.length) {
        if (shown) this.renderer.removeActor(g.actor);
        continue;
      }
      const points = these.map((c) => ({ x: c.point!.x ?? 0, y: c.point!.y ?? 0, z: c.point!.z ?? 0 }));
      setSpheres(g.polyData, points, these.map((c) => Math.max(2, 1.5 * (c.radiusMm ?? 0))));
      if (!shown) this.renderer.addActor(g.actor);
    }
  }

  /** Turns the camera to look at `p` from where it looks now, from `distance` mm. */
  focus(p: Vec3, distance: number): void {
    const camera = this.renderer.getActiveCamera();
    const [px, py, pz] = camera.getPosition();
    const [fx, fy, fz] = camera.getFocalPoint();
    const d = Math.hypot(px - fx, py - fy, pz - fz) || 1;
    camera.setFocalPoint(p.x, p.y, p.z);
    camera.setPosition(p.x + ((px - fx) / d) * distance, p.y + ((py - fy) / d) * distance, p.z + ((pz - fz) / d) * distance);
    this.renderer.resetCameraClippingRange();
    this.framed = true;
  }

  /** The camera's focal point (RAS mm). */
  focalPoint(): Vec3 {
    const [x, y, z] = this.renderer.getActiveCamera().getFocalPoint();
    return { x, y, z };
  }

  /** The point of one of the surfaces `names` drawn at page position (`x`, `y`), nearest the
   * camera; null where none is. */
  pickSurface(x: number, y: number, names: readonly string[]): Vec3 | null {
    const { rect, scale } = this.frame();
    const actors = names.flatMap((n) => {
      const a = this.entries.get(n)?.actor;
      return a && a.getVisibility() ? [a] : [];
    });
    if (!actors.length) return null;
    this.picker.setPickFromList(true);
    this.picker.initializePickList();
    for (const a of actors) this.picker.addPickList(a);
    this.picker.pick([(x - rect.left) * scale, (rect.bottom - y) * scale, 0], this.renderer);
    if (!this.picker.getActors().length) return null;
    const [px, py, pz] = this.picker.getPickPosition();
    return { x: px, y: py, z: pz };
  }

  /** Shows the control grid `points` (row-major, `m` × `n`) as spheres joined by lines, or
   * hides it (`points` empty). */
  showGrid(points: readonly Vec3[], m: number, n: number): void {
    const show = points.length > 0 && points.length === m * n;
    for (const g of [this.spheres, this.lines]) {
      if (show && !this.renderer.hasViewProp(g.actor)) this.renderer.addActor(g.actor);
      if (!show && this.renderer.hasViewProp(g.actor)) this.renderer.removeActor(g.actor);
    }
    if (!show) return;
    setSpheres(this.spheres.polyData, points, sphereRadius(points));
    setGridLines(this.lines.polyData, points, m, n);
  }

  /** Shows `traces` as polylines (`closed`: rings) with a small sphere at each point, or
   * hides them (none). */
  showTraces(traces: readonly Vec3[][], closed: boolean): void {
    const points = traces.flat();
    const show = points.length > 0;
    for (const g of [this.traceLines, this.tracePoints]) {
      if (show && !this.renderer.hasViewProp(g.actor)) this.renderer.addActor(g.actor);
      if (!show && this.renderer.hasViewProp(g.actor)) this.renderer.removeActor(g.actor);
    }
    if (!show) return;
    setSpheres(this.tracePoints.polyData, points, 1);
    const xyz = new Float32Array(3 * points.length);
    points.forEach((p, k) => xyz.set([p.x, p.y, p.z], 3 * k));
    const cells: number[] = [];
    let first = 0;
    for (const t of traces) {
      const ids = t.map((_, k) => first + k);
      if (closed && t.length > 2) ids.push(first);
      cells.push(ids.length, ...ids);
      first += t.length;
    }
    this.traceLines.polyData.getPoints().setData(xyz, 3);
    this.traceLines.polyData.getLines().setData(Uint32Array.from(cells));
    this.traceLines.polyData.modified();
  }

  /** The mesh shown as `name`. */
  mesh(name: string): Mesh | null {
    return this.entries.get(name)?.mesh ?? null;
  }

  /** Where world point `p` is drawn on the page. */
  toScreen(p: Vec3): ScreenPoint {
    const { rect, scale } = this.frame();
    const [x, y, depth] = this.gl.worldToDisplay(p.x, p.y, p.z, this.renderer);
    return { x: rect.left + x / scale, y: rect.bottom - y / scale, depth };
  }

  /** The world point drawn at page position (`x`, `y`) and normalised depth `depth`. */
  fromScreen(s: ScreenPoint): Vec3 {
    const { rect, scale } = this.frame();
    const [x, y, z] = this.gl.displayToWorld((s.x - rect.left) * scale, (rect.bottom - s.y) * scale, s.depth, this.renderer);
    return { x, y, z };
  }

  /** Renders; the first time anything is shown, frames it seen from the front (anterior). */
  render(): void {
    if (!this.framed && this.entries.size) {
      const camera = this.renderer.getActiveCamera();
      camera.setFocalPoint(0, 0, 0);
      camera.setPosition(-0.35, 1, 0.25); // RAS: from anterior (a little from the left and above), superior up
      camera.setViewUp(0, 0, 1);
      this.renderer.resetCamera();
      this.framed = true;
    }
    this.renderWindow.render();
  }

  /** The canvas' place on the page and its framebuffer pixels per CSS pixel. */
  private frame(): { rect: DOMRect; scale: number } {
    const rect = this.gl.getCanvas()!.getBoundingClientRect();
    const [width] = this.gl.getFramebufferSize();
    return { rect, scale: rect.width > 0 ? width / rect.width : 1 };
  }

  private paintClasses(e: Entry): void {
    const { colors } = e;
    const classes = e.mesh.classes;
    if (!colors || !classes) return;
    for (let i = 0; i < classes.length; i++) {
      const rgba = MARGIN_CLASS_RGBA[classes[i]!] ?? MARGIN_CLASS_RGBA[0]!;
      for (let c = 0; c < 4; c++) colors[4 * i + c] = Math.round(255 * rgba[c]!);
    }
    e.polyData.getPointData().getScalars()?.modified();
  }
}

function gridActor(lineWidth: number, rgb: Rgb = GRID_RGB): { polyData: PolyData; actor: ReturnType<typeof vtkActor.newInstance> } {
  const polyData = vtkPolyData.newInstance();
  const mapper = vtkMapper.newInstance({ scalarVisibility: false });
  mapper.setInputData(polyData);
  const actor = vtkActor.newInstance();
  actor.setMapper(mapper);
  actor.getProperty().setColor(...rgb);
  actor.getProperty().setLineWidth(lineWidth);
  actor.setPickable(false);
  return { polyData, actor };
}

/** Sphere radius for a grid: a twentieth of its mean edge length (2 mm when degenerate). */
function sphereRadius(points: readonly Vec3[]): number {
  let lo = [Infinity, Infinity, Infinity];
  let hi = [-Infinity, -Infinity, -Infinity];
  for (const p of points) {
    lo = [Math.min(lo[0]!, p.x), Math.min(lo[1]!, p.y), Math.min(lo[2]!, p.z)];
    hi = [Math.max(hi[0]!, p.x), Math.max(hi[1]!, p.y), Math.max(hi[2]!, p.z)];
  }
  const diagonal = Math.hypot(hi[0]! - lo[0]!, hi[1]! - lo[1]!, hi[2]! - lo[2]!);
  return diagonal > 0 ? Math.max(1, diagonal / (20 * Math.sqrt(points.length))) : 2;
}

const SPHERE = (() => {
  const s = vtkSphereSource.newInstance({ radius: 1, thetaResolution: 16, phiResolution: 12 });
  const out = s.getOutputData();
  return { points: out.getPoints().getData() as Float32Array, polys: out.getPolys().getData() as Uint32Array };
})();

/** One sphere of `radius` (one for all, or one per point) at each point, all in one polydata. */
function setSpheres(polyData: PolyData, points: readonly Vec3[], radius: number | readonly number[]): void {
  const per = SPHERE.points.length / 3;
  const xyz = new Float32Array(3 * per * points.length);
  const cells = new Uint32Array(SPHERE.polys.length * points.length);
  points.forEach((p, k) => {
    const r = typeof radius === "number" ? radius : radius[k]!;
    for (let v = 0; v < per; v++) {
      const o = 3 * (k * per + v);
      xyz[o] = p.x + r * SPHERE.points[3 * v]!;
      xyz[o + 1] = p.y + r * SPHERE.points[3 * v + 1]!;
      xyz[o + 2] = p.z + r * SPHERE.points[3 * v + 2]!;
    }
    const c0 = k * SPHERE.polys.length;
    for (let c = 0; c < SPHERE.polys.length; ) {
      const count = SPHERE.polys[c]!;
      cells[c0 + c] = count;
      for (let t = 1; t <= count; t++) cells[c0 + c + t] = SPHERE.polys[c + t]! + k * per;
      c += count + 1;
    }
  });
  polyData.getPoints().setData(xyz, 3);
  polyData.getPolys().setData(cells);
  polyData.modified();
}

/** The grid's rows and columns as polylines. */
function setGridLines(polyData: PolyData, points: readonly Vec3[], m: number, n: number): void {
  const xyz = new Float32Array(3 * points.length);
  points.forEach((p, k) => xyz.set([p.x, p.y, p.z], 3 * k));
  const cells: number[] = [];
  for (let i = 0; i < m; i++) cells.push(n, ...Array.from({ length: n }, (_, j) => i * n + j));
  for (let j = 0; j < n; j++) cells.push(m, ...Array.from({ length: m }, (_, i) => i * n + j));
  polyData.getPoints().setData(xyz, 3);
  polyData.getLines().setData(Uint32Array.from(cells));
  polyData.modified();
}
