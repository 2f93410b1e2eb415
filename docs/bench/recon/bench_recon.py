"""Reconstruction benchmark (issue #4, "Performance"): in one run on the same label maps, our PSR
(d = 7) and MCSD through the ``resecta`` CLI, 3D Slicer's closed-surface conversion (slicer-core)
and Kazhdan's Poisson reconstruction at the same depth on our oriented points (Open3D).

Timed regions (wall clock, best of ``--repeats``):
- resecta psr / mcsd: the whole ``resecta reconstruct`` process (read label map → write mesh).
- Slicer: ``convert`` = ``rule.Convert(segment)`` only; ``total`` = Slicer's ITK reader + oriented
  image + segmentation set-up + convert (in this Python process; interpreter start-up not counted).
- Open3D: ``convert`` = ``create_from_point_cloud_poisson`` only; ``total`` = reading our points PLY
  + building the point cloud + convert.
Every mesh is then measured by ``resecta measure`` against our oriented points (the same reference
for all methods); a Python cross-check (polygons, enclosed volume, watertight, distances from the
same points) is recorded beside it.

Until ``resecta reconstruct`` exists, our methods are skipped with a message and the anchors run
on test-only oriented points computed here from the mask (``anchors.gradient_points``).

``--patient`` instead benchmarks a whole patient map (issue #16): an MSD Task08 case as a label map
with the automatic liver mask as parenchyma (1) and the case's tumour (2) and vessel (3) labels
inside that mask only, as when vessels are segmented in the liver (they fall apart into pieces);
``--z-repeat 2`` repeats every slice (512×512×132 for case 002). It reports ``resecta models``
(one model per segment, the default, against ``--split-components --min-component-mm3 0``, one
per component) and, per segment, our MCSD (``select_ms + reconstruct_ms``: label map in memory
→ mesh, both cores and one) against Slicer's ``rule.Convert`` of the same label value.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import anchors

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
SHARED = REPO.parent / "shared" / "test-data" / "liver"
DEFAULT_INPUTS = [
    ("totalsegmentator-v1-liver", str(SHARED / "totalsegmentator-example/v1_liver.nii.gz"), "1"),
    (
        "msd-hepaticvessel-002-liver-pred",
        str(SHARED / "msd-task08-hepaticvessel/hepaticvessel_002_liver_pred.nii.gz"),
        "1",
    ),
    ("phantom-demo-parenchyma", "phantom", "1"),
]
METHODS = ["resecta-psr", "resecta-mcsd", "slicer", "open3d-poisson"]


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------- resecta CLI


class Resecta:
    def __init__(self, binary: str):
        self.bin = binary
        self.exists = Path(binary).is_file() and os.access(binary, os.X_OK)
        self.reconstruct = self.exists and self._has("reconstruct")
        self.measure_ok = self.exists and self._has("measure")

    def _has(self, sub: str) -> bool:
        r = subprocess.run([self.bin, sub, "--help"], capture_output=True, text=True)
        return r.returncode == 0

    def run_json(self, args: list[str]) -> tuple[dict, float]:
        t0 = time.perf_counter()
        r = subprocess.run([self.bin, *args], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if r.returncode != 0:
            raise RuntimeError(
                f"resecta {' '.join(args[:2])} failed ({r.returncode}): {r.stderr.strip()[-500:]}"
            )
        return json.loads(r.stdout), wall

    def version(self) -> str:
        if not self.exists:
            return "absent"
        r = subprocess.run([self.bin, "--version"], capture_output=True, text=True)
        return r.stdout.strip()


# ---------------------------------------------------------------- machine


def machine() -> dict:
    cpu = "unknown"
    try:
        for ln in Path("/proc/cpuinfo").read_text().splitlines():
            if ln.startswith("model name"):
                cpu = ln.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f"{kb / 2**20:.1f} GiB"
    except (OSError, ValueError, IndexError):
        pass
    versions = {"python": platform.python_version(), "numpy": np.__version__}
    for mod, name in (("vtk", "vtk"), ("open3d", "open3d"), ("nibabel", "nibabel")):
        try:
            versions[name] = __import__(mod).__version__
        except Exception:  # noqa: BLE001 (report whatever is missing, never fail here)
            versions[name] = "absent"
    try:
        from importlib.metadata import version  # noqa: PLC0415

        versions["slicer-core"] = version("slicer-core")
    except Exception:  # noqa: BLE001
        versions["slicer-core"] = "absent"
    import vtk  # noqa: PLC0415

    return {
        "cpu": cpu,
        "logical_cpus": os.cpu_count(),
        "usable_cpus": len(os.sched_getaffinity(0)),
        "memory": mem,
        "load_average_at_start": os.getloadavg(),
        "os": platform.platform(),
        "vtk_smp_backend": vtk.vtkSMPTools.GetBackend(),
        "versions": versions,
    }


def git_commit() -> str:
    r = subprocess.run(
        ["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    return r.stdout.strip() or "unknown"


# ---------------------------------------------------------------- one input


def best(runs: list[dict], key: str) -> float:
    return min(r[key] for r in runs)


def measure(rs: Resecta, mesh: Path, inp: str, labels: str, ref_pts) -> dict:
    """``resecta measure`` (when available) plus the Python cross-check."""
    v, f = anchors.read_mesh(mesh)
    out = {"python": anchors.mesh_metrics(v, f, ref_pts)}
    if rs.measure_ok:
        try:
            m, _ = rs.run_json(
                ["measure", str(mesh), "--reference", inp, "--labels", labels, "--json"]
            )
            out["resecta"] = m
        except (RuntimeError, json.JSONDecodeError) as e:
            out["resecta_error"] = str(e)
    return out


def primary(entry: dict) -> dict:
    """The metrics the tables use: resecta measure's when present, else the Python cross-check."""
    m = entry.get("metrics", {})
    return m.get("resecta") or m.get("python") or {}


def bench_input(name, inp, labels, rs: Resecta, args, work: Path) -> dict:
    label_list = [int(x) for x in labels.split(",")]
    wd = work / name
    wd.mkdir(parents=True, exist_ok=True)
    res: dict = {"name": name, "input": inp, "labels": labels, "methods": {}}
    arr, affine = anchors.read_label_numpy(inp)
    res["dims"] = list(arr.shape)
    res["spacing_mm"] = [float(x) for x in np.linalg.norm(affine[:3, :3], axis=0)]
    res["mask_volume_ml"] = anchors.mask_volume_ml(inp, label_list)
    res["geometry_check_mm"] = anchors.check_geometry(inp)
    del arr
    log(
        f"== {name}: {inp} labels {labels}, dims {res['dims']}, mask {res['mask_volume_ml']:.2f} ml"
    )

    points_ply = wd / "points.ply"
    meshes: dict[str, Path] = {}

    # Ours (whole process, best of N).
    if rs.reconstruct:
        for method, extra in (
            (
                "resecta-psr",
                ["--method", "psr", "--depth", str(args.depth), "--points-out", str(points_ply)],
            ),
            ("resecta-mcsd", ["--method", "mcsd", "--smoothing", "0.5", "--decimation", "0"]),
        ):
            mesh = wd / f"{method}.vtp"
            runs = []
            try:
                for _ in range(args.repeats):
                    js, wall = rs.run_json(
                        [
                            "reconstruct",
                            inp,
                            "--labels",
                            labels,
                            *extra,
                            "--out",
                            str(mesh),
                            "--json",
                        ]
                    )
                    runs.append({"process_s": wall, "cli_time_ms": js.get("time_ms"), "cli": js})
            except (RuntimeError, json.JSONDecodeError) as e:
                res["methods"][method] = {"error": str(e)}
                log(f"  {method}: FAILED {e}")
                continue
            res["methods"][method] = {
                "time_s": min(r["cli"]["reconstruct_ms"] for r in runs) / 1000.0,
                "total_s": min(
                    r["cli"]["read_ms"] + r["cli"].get("select_ms", 0) + r["cli"]["reconstruct_ms"]
                    for r in runs
                )
                / 1000.0,
                "process_s": best(runs, "process_s"),
                "timed_region": "reconstruct: mask → mesh in memory (PSR: oriented points, solve, "
                "marching cubes, normals); total: read label map + reconstruct; process_s: the "
                "whole `resecta reconstruct` process incl. writing the mesh",
                "runs_s": [r["process_s"] for r in runs],
                "cli_time_ms": [r["cli_time_ms"] for r in runs],
                "cli_json": runs[-1]["cli"],
            }
            meshes[method] = mesh
            log(f"  {method}: {res['methods'][method]['time_s']:.3f} s")
    else:
        msg = f"{rs.bin} " + ("does not exist" if not rs.exists else "has no `reconstruct`")
        log(f"  SKIP resecta-psr/resecta-mcsd: {msg}")
        for method in ("resecta-psr", "resecta-mcsd"):
            res["methods"][method] = {"skipped": msg}

    # Reference oriented points: ours, or the test-only gradient points.
    if rs.reconstruct and points_ply.is_file():
        res["reference_points"] = "resecta --points-out (PSR's oriented points)"
    else:
        pos, nrm = anchors.gradient_points(inp, label_list)
        anchors.write_points_ply(points_ply, pos, nrm)
        res["reference_points"] = (
            "TEST ONLY: Python central-difference gradient of the mask, "
            "half-voxel outward shift (resecta --points-out unavailable)"
        )
    ref_pos, _ = anchors.read_points_ply(points_ply)
    res["reference_point_count"] = int(len(ref_pos))

    # Slicer.
    if len(label_list) != 1:
        res["methods"]["slicer"] = {"skipped": "Slicer anchor takes a single label value"}
    else:
        mesh = wd / "slicer.ply"
        runs = []
        for k in range(args.repeats):
            _, t = anchors.slicer_closed_surface(
                inp, label_list[0], 0.5, 0.0, out=mesh if k == 0 else None
            )
            runs.append(t)
        res["methods"]["slicer"] = {
            "time_s": best(runs, "convert"),
            "total_s": best(runs, "total"),
            "timed_region": "convert: rule.Convert(segment); total: reader + set-up + convert",
            "runs": runs,
            "parameters": anchors.SLICER_DEFAULTS,
        }
        meshes["slicer"] = mesh
        log(
            f"  slicer: convert {best(runs, 'convert'):.3f} s, "
            f"read+convert {best(runs, 'total'):.3f} s"
        )

    # Open3D (Kazhdan's PoissonRecon inside) on the same oriented points.
    try:
        mesh = wd / "open3d-poisson.ply"
        runs = []
        for k in range(args.repeats):
            _, t = anchors.open3d_poisson(points_ply, args.depth, 1.1, out=mesh if k == 0 else None)
            runs.append(t)
        res["methods"]["open3d-poisson"] = {
            "time_s": best(runs, "convert"),
            "total_s": best(runs, "total"),
            "timed_region": "convert: create_from_point_cloud_poisson(depth, scale=1.1, "
            "n_threads=-1); total: read points PLY + point cloud + convert",
            "runs": runs,
        }
        meshes["open3d-poisson"] = mesh
        log(f"  open3d-poisson: convert {best(runs, 'convert'):.3f} s")
    except ImportError as e:
        res["methods"]["open3d-poisson"] = {"skipped": f"open3d not importable: {e}"}

    for method, mesh in meshes.items():
        res["methods"][method]["mesh"] = str(mesh)
        res["methods"][method]["metrics"] = measure(rs, mesh, inp, labels, ref_pos)
        p = primary(res["methods"][method])
        log(
            f"  {method}: {p.get('polys')} polys, mean {p.get('mean_mm', float('nan')):.3f} mm, "
            f"{p.get('volume_ml', float('nan')):.2f} ml, watertight {p.get('watertight')}"
        )
    res["targets"] = targets(res)
    return res


# ---------------------------------------------------------------- targets


def targets(res: dict) -> list[dict]:
    m = res["methods"]

    def get(method):
        e = m.get(method, {})
        return (e, primary(e)) if "time_s" in e else (None, None)

    out = []
    psr, psr_m = get("resecta-psr")
    mcsd, mcsd_m = get("resecta-mcsd")
    sl, sl_m = get("slicer")
    o3, o3_m = get("open3d-poisson")

    name = "PSR d=7 faster than Slicer's conversion, mean ≤ 1.0 mm, ≥ 4× fewer polygons"
    if psr and sl:
        ok = (
            psr["time_s"] < sl["time_s"]
            and psr_m["mean_mm"] <= 1.0
            and psr_m["polys"] * 4 <= sl_m["polys"]
        )
        detail = (
            f"PSR {psr['time_s']:.3f} s reconstruct ({psr['total_s']:.3f} s read+reconstruct, "
            f"{psr['process_s']:.3f} s whole process) vs Slicer {sl['time_s']:.3f} s convert "
            f"({sl['total_s']:.3f} s read+convert); mean {psr_m['mean_mm']:.3f} mm; "
            f"polygons {psr_m['polys']} vs {sl_m['polys']} "
            f"({sl_m['polys'] / max(psr_m['polys'], 1):.2f}× fewer)"
        )
        out.append({"target": name, "met": ok, "detail": detail})
    else:
        out.append({"target": name, "met": None, "detail": "not run (resecta reconstruct absent)"})

    name = (
        "MCSD ≥ 2× faster than Slicer at matching polygon count (±10 %) and accuracy "
        "(mean within 10 % or 0.05 mm)"
    )
    if mcsd and sl:
        match_p = abs(mcsd_m["polys"] / sl_m["polys"] - 1.0) <= 0.10
        match_a = mcsd_m["mean_mm"] <= max(sl_m["mean_mm"] * 1.10, sl_m["mean_mm"] + 0.05)
        ok = mcsd["time_s"] * 2 <= sl["time_s"] and match_p and match_a
        detail = (
            f"MCSD {mcsd['time_s']:.3f} s reconstruct ({mcsd['total_s']:.3f} s read+reconstruct, "
            f"{mcsd['process_s']:.3f} s whole process) vs Slicer {sl['time_s']:.3f} s convert "
            f"({sl['time_s'] / mcsd['time_s']:.2f}×; read+convert {sl['total_s']:.3f} s, "
            f"{sl['total_s'] / mcsd['total_s']:.2f}×); polygons "
            f"{mcsd_m['polys']} vs {sl_m['polys']}; mean {mcsd_m['mean_mm']:.3f} vs "
            f"{sl_m['mean_mm']:.3f} mm"
        )
        out.append({"target": name, "met": ok, "detail": detail})
    else:
        out.append({"target": name, "met": None, "detail": "not run (resecta reconstruct absent)"})

    name = "PSR ≥ 2× faster than PoissonRecon (Open3D) at equal depth, mean within 10 %"
    if psr and o3:
        ok = psr["time_s"] * 2 <= o3["time_s"] and psr_m["mean_mm"] <= o3_m["mean_mm"] * 1.10
        detail = (
            f"PSR {psr['time_s']:.3f} s reconstruct incl. oriented points vs Open3D "
            f"{o3['time_s']:.3f} s solve on given points ({o3['time_s'] / psr['time_s']:.2f}×); mean "
            f"{psr_m['mean_mm']:.3f} vs {o3_m['mean_mm']:.3f} mm"
        )
        out.append({"target": name, "met": ok, "detail": detail})
    else:
        out.append({"target": name, "met": None, "detail": "not run (resecta reconstruct absent)"})
    return out


# ---------------------------------------------------------------- reports


def fmt(x, spec):
    return "—" if x is None else format(x, spec)


def write_markdown(path: Path, report: dict) -> None:
    mc = report["machine"]
    lines = [
        "# Reconstruction benchmark: resecta PSR / MCSD vs 3D Slicer and PoissonRecon",
        "",
        f"Run {report['date']} at commit `{report['commit']}`, `{report['resecta_version']}`, "
        f"depth {report['depth']}, best of {report['repeats']} (wall clock).",
        "",
        f"Machine: {mc['cpu']}, {mc['usable_cpus']} usable of {mc['logical_cpus']} logical CPUs, "
        f"{mc['memory']} RAM, load average at start "
        f"{', '.join(f'{x:.2f}' for x in mc['load_average_at_start'])} (shared machine); "
        f"VTK SMP backend {mc['vtk_smp_backend']}; "
        + ", ".join(f"{k} {v}" for k, v in mc["versions"].items())
        + ".",
        "",
        "Timed regions: **resecta** = mask → mesh in memory as reported by `resecta reconstruct "
        "--json` (read + reconstruct in brackets; the whole process including writing the mesh "
        "is in results.json as `process_s`); **Slicer** = `vtkBinaryLabelmapToClosedSurfaceConversionRule.Convert` only "
        "(read+convert in brackets: Slicer's ITK reader + segmentation set-up + convert, "
        "in-process); "
        "**Open3D** = `create_from_point_cloud_poisson` only (read points + solve in brackets), "
        "on the oriented points our PSR writes. Metrics by `resecta measure` against those points "
        "(the Python cross-check where it is unavailable). Meshes are RAS.",
        "",
    ]
    for r in report["inputs"]:
        lines += [
            f"## {r['name']}",
            "",
            f"`{r['input']}`, label(s) {r['labels']}, dims {r['dims']}, spacing "
            f"{', '.join(f'{s:.3g}' for s in r['spacing_mm'])} mm, mask volume "
            f"{r['mask_volume_ml']:.2f} ml; reference: {r['reference_points']} "
            f"({r['reference_point_count']} points).",
            "",
            "| method | time (s) | polygons | mean (mm) | p95 (mm) | max (mm) | volume (ml) "
            "| vol. vs mask | watertight |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for method in METHODS:
            e = r["methods"].get(method, {})
            if "time_s" not in e:
                reason = e.get("skipped") or e.get("error") or "not run"
                lines.append(f"| {method} | skipped: {reason} | | | | | | | |")
                continue
            p = primary(e)
            t = fmt(e["time_s"], ".3f")
            if "total_s" in e:
                t += f" ({e['total_s']:.3f})"
            vol = p.get("volume_ml")
            rel = None if vol is None else (vol / r["mask_volume_ml"] - 1.0) * 100.0
            wt = p.get("watertight")
            py = e["metrics"]["python"]
            if not py["watertight"]:
                wt = (
                    f"{wt} ({py['boundary_edges']} boundary, "
                    f"{py['nonmanifold_edges']} non-manifold edges)"
                )
            lines.append(
                f"| {method} | {t} | {p.get('polys')} | {fmt(p.get('mean_mm'), '.3f')} | "
                f"{fmt(p.get('p95_mm'), '.3f')} | {fmt(p.get('max_mm'), '.3f')} | "
                f"{fmt(vol, '.2f')} | {fmt(rel, '+.2f')} % | {wt} |"
            )
        lines += ["", "Targets:", ""]
        for t in r["targets"]:
            state = {True: "**met**", False: "**not met**", None: "not run"}[t["met"]]
            lines.append(f"- {state}: {t['target']} — {t['detail']}")
        lines.append("")
    lines += ["![time and accuracy](results.svg)", ""]
    path.write_text("\n".join(lines))


def plot(report: dict, stem: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5))
    inputs = report["inputs"]
    width = 0.8 / len(METHODS)
    markers = dict(zip(METHODS, "o^sD", strict=True))
    for k, method in enumerate(METHODS):
        xs, ys = [], []
        for i, r in enumerate(inputs):
            e = r["methods"].get(method, {})
            if "time_s" in e:
                xs.append(i + (k - (len(METHODS) - 1) / 2) * width)
                ys.append(e["time_s"])
        if ys:
            ax1.bar(xs, ys, width, label=method, color=f"C{k}")
    ax1.set_xticks(range(len(inputs)), [r["name"] for r in inputs], rotation=12, fontsize=8)
    ax1.set_ylabel("time (s), best of %d" % report["repeats"])
    ax1.set_yscale("log")
    ax1.set_title("Time per method, mask → mesh in memory (best of 3)", fontsize=9)
    ax1.legend(fontsize=8)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, r in enumerate(inputs):
        for method in METHODS:
            e = r["methods"].get(method, {})
            p = primary(e) if "time_s" in e else {}
            if p.get("mean_mm") is not None:
                ax2.scatter(
                    p["polys"],
                    p["mean_mm"],
                    marker=markers[method],
                    color=colors[i % len(colors)],
                    s=50,
                )
    for method in METHODS:
        ax2.scatter([], [], marker=markers[method], color="gray", label=method)
    for i, r in enumerate(inputs):
        ax2.scatter([], [], marker="s", color=colors[i % len(colors)], label=r["name"])
    ax2.set_xscale("log")
    ax2.set_xlabel("polygons")
    ax2.set_ylabel("mean point-to-surface distance (mm)")
    ax2.set_title("Accuracy vs polygons (same oriented points for all)", fontsize=9)
    ax2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(stem.with_suffix(".png"), dpi=110)
    fig.savefig(stem.with_suffix(".svg"))
    plt.close(fig)


# ---------------------------------------------------------------- patient map (issue #16)

PATIENT_ROLES = '{"parenchyma":[1],"tumor":[2],"vessel":[3]}'
SEGMENTS = {1: "parenchyma", 2: "tumour", 3: "vessel"}


def patient_map(case: str, z_repeat: int, work: Path) -> Path:
    """The MSD case as a patient label map: liver mask 1, tumour 2 and vessel 3 inside it."""
    import nibabel as nib  # noqa: PLC0415

    folder = SHARED / "msd-task08-hepaticvessel"
    img = nib.load(folder / f"hepaticvessel_{case}_label.nii.gz")
    msd = np.asarray(img.dataobj)
    liver = np.asarray(nib.load(folder / f"hepaticvessel_{case}_liver_pred.nii.gz").dataobj) == 1
    labels = np.where(liver, 1, 0).astype(np.uint8)
    labels[liver & (msd == 1)] = 3
    labels[liver & (msd == 2)] = 2
    affine = img.affine.copy()
    if z_repeat > 1:
        labels = np.repeat(labels, z_repeat, axis=2)
        affine[:3, 2] /= z_repeat
        affine[:3, 3] -= affine[:3, 2] * (z_repeat - 1) / 2  # keep slice centres in place
    out = work / "patient" / f"msd-{case}-liver-clipped-z{z_repeat}.nii.gz"
    out.parent.mkdir(parents=True, exist_ok=True)
    nib.save(nib.Nifti1Image(labels, affine), out)
    return out


def with_threads(threads: int | None):
    env = dict(os.environ)
    if threads is not None:
        env["RAYON_NUM_THREADS"] = str(threads)
    return env


def run_json(rs: Resecta, args: list[str], threads: int | None = None) -> dict:
    r = subprocess.run([rs.bin, *args], capture_output=True, text=True, env=with_threads(threads))
    if r.returncode != 0:
        raise RuntimeError(f"resecta {' '.join(args[:2])} failed: {r.stderr.strip()[-500:]}")
    return json.loads(r.stdout)


def server_reconstructions(rs: Resecta, path: Path, repeats: int) -> dict:
    """``ReconstructDone.elapsed_s`` of `resecta serve` (sessions in memory) through the Python
    client, per mode: what a client waits for (models built, encoded and stored)."""
    import nibabel as nib  # noqa: PLC0415

    sys.path.insert(0, str(REPO / "clients" / "python" / "src"))
    from resecta_client import Client  # noqa: PLC0415

    proc = subprocess.Popen(
        [rs.bin, "serve", "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )
    try:
        bound = json.loads(proc.stdout.readline())
        img = nib.load(path)
        with Client(bound["grpc"]) as client:
            session = client.create_session("bench")
            session.upload_label_map(
                np.asarray(img.dataobj).transpose(2, 1, 0), img.affine, json.loads(PATIENT_ROLES)
            )
            time.sleep(3)  # the planner's set-up after an upload is done
            out = {}
            for mode, options in (
                ("per_segment", {}),
                ("per_component", {"split_components": True, "min_component_mm3": 0}),
            ):
                runs = [session.reconstruct("psr", **options) for _ in range(repeats)]
                out[mode] = {
                    "elapsed_s": min(r.elapsed_s for r in runs),
                    "runs_s": [r.elapsed_s for r in runs],
                    "models": len(runs[-1]),
                }
                log(f"  server {mode}: {len(runs[-1])} models, {out[mode]['elapsed_s']:.3f} s")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return out


def bench_patient(rs: Resecta, path: Path, args, work: Path) -> dict:
    arr, _ = anchors.read_label_numpy(path)
    res: dict = {"input": str(path), "dims": list(arr.shape), "roles": PATIENT_ROLES}
    log(f"== patient map {path}, dims {res['dims']}")
    models = {}
    for mode, extra in (
        ("per_segment", []),
        ("per_component", ["--split-components", "--min-component-mm3", "0"]),
    ):
        runs = [
            run_json(
                rs,
                ["models", str(path), "--roles", PATIENT_ROLES, "--out-dir",
                 str(work / "patient" / mode), *extra, "--json"],
            )
            for _ in range(args.repeats)
        ]
        last = runs[-1]
        counts: dict[str, int] = {}
        for m in last["models"]:
            counts[m["role"]] = counts.get(m["role"], 0) + 1
        models[mode] = {
            "reconstruct_s": min(r["reconstruct_ms"] for r in runs) / 1000.0,
            "runs_s": [r["reconstruct_ms"] / 1000.0 for r in runs],
            "models": len(last["models"]),
            "per_role": counts,
            "dropped": last["dropped"],
            "min_component_mm3": last["min_component_mm3"],
        }
        log(f"  models {mode}: {len(last['models'])} models {counts}, "
            f"{models[mode]['reconstruct_s']:.3f} s, dropped {last['dropped']}")
    res["models"] = models
    res["server"] = server_reconstructions(rs, path, args.repeats)
    segments = []
    for label, name in SEGMENTS.items():
        ours = {}
        for key, threads in (("ours_s", None), ("ours_1_thread_s", 1)):
            runs = [
                run_json(
                    rs,
                    ["reconstruct", str(path), "--labels", str(label), "--method", "mcsd",
                     "--out", str(work / "patient" / f"mcsd-{label}.vtp"), "--json"],
                    threads,
                )
                for _ in range(args.repeats)
            ]
            ours[key] = min(r.get("select_ms", 0) + r["reconstruct_ms"] for r in runs) / 1000.0
            ours["polys"] = runs[-1]["polys"]
        slicer = [
            anchors.slicer_closed_surface(path, label, 0.5, 0.0)[1]["convert"]
            for _ in range(args.repeats)
        ]
        poly, _ = anchors.slicer_closed_surface(path, label, 0.5, 0.0)
        seg = {
            "label": label,
            "segment": name,
            **ours,
            "slicer_s": min(slicer),
            "slicer_runs_s": slicer,
            "slicer_polys": poly.GetNumberOfPolys(),
        }
        seg["ratio"] = seg["ours_s"] / seg["slicer_s"]
        seg["ratio_1_thread"] = seg["ours_1_thread_s"] / seg["slicer_s"]
        segments.append(seg)
        log(f"  segment {label} {name}: ours {seg['ours_s']:.3f} s "
            f"(1 thread {seg['ours_1_thread_s']:.3f}) vs Slicer {seg['slicer_s']:.3f} s: "
            f"{seg['ratio']:.2f} ({seg['ratio_1_thread']:.2f}); polygons {seg['polys']} vs "
            f"{seg['slicer_polys']}")
    res["segments"] = segments
    total = {k: sum(s[k] for s in segments) for k in ("ours_s", "ours_1_thread_s", "slicer_s")}
    total["ratio"] = total["ours_s"] / total["slicer_s"]
    total["ratio_1_thread"] = total["ours_1_thread_s"] / total["slicer_s"]
    res["total"] = total
    return res


def write_patient_markdown(path: Path, report: dict) -> None:
    mc = report["machine"]
    lines = [
        "# One model per segment: reconstruction time and MCSD vs 3D Slicer (issue #16)",
        "",
        f"Run {report['date']} at commit `{report['commit']}`, `{report['resecta_version']}` "
        f"(release build), best of {report['repeats']} (wall clock). Machine: {mc['cpu']}, "
        f"{mc['usable_cpus']} usable of {mc['logical_cpus']} logical CPUs (virtualised), "
        f"{mc['memory']} RAM, load average at start "
        f"{', '.join(f'{x:.2f}' for x in mc['load_average_at_start'])} (shared machine); VTK SMP "
        f"backend {mc['vtk_smp_backend']} (Slicer on one core); "
        + ", ".join(f"{k} {v}" for k, v in mc["versions"].items())
        + ".",
        "",
        "Label map: MSD Task08 case with the automatic liver mask as parenchyma (1) and the "
        "case's tumour (2) and vessel (3) labels inside that mask only; roles "
        f"`{PATIENT_ROLES}`. Reproduce: `python docs/bench/recon/bench_recon.py --patient "
        "[--case 002] [--z-repeat 1|2]`.",
        "",
    ]
    for r in report["patients"]:
        m = r["models"]
        lines += [
            f"## {Path(r['input']).name}, dims {r['dims']}",
            "",
            "`resecta models` (parenchyma by PSR d = 7, the server's default; label map in memory "
            "→ every mesh in memory):",
            "",
            "| models | count | per role | dropped specks | time (s) |",
            "|---|---|---|---|---|",
        ]
        for mode, title in (("per_segment", "one per segment (default)"),
                            ("per_component", "one per component (`--split-components`, "
                             "`--min-component-mm3 0`)")):
            e = m[mode]
            dropped = ", ".join(
                f"{d['role']}: {d['components']} ({d['volume_ml'] * 1000:.1f} mm³)"
                for d in e["dropped"]) or "none"
            roles = ", ".join(f"{k} {v}" for k, v in e["per_role"].items())
            lines.append(f"| {title} | {e['models']} | {roles} | {dropped} | "
                         f"{e['reconstruct_s']:.3f} |")
        srv = r["server"]
        lines += [
            "",
            "Through the server (`resecta serve`, sessions in memory, the Python client): "
            "`ReconstructDone.elapsed_s`, models built, encoded and stored — "
            f"{srv['per_segment']['models']} models in {srv['per_segment']['elapsed_s']:.3f} s "
            f"per segment, {srv['per_component']['models']} in "
            f"{srv['per_component']['elapsed_s']:.3f} s per component.",
            "",
            "MCSD per segment (Slicer's defaults: smoothing 0.5, no decimation): ours = "
            "`select_ms + reconstruct_ms` of `resecta reconstruct --method mcsd` (label map in "
            "memory → mesh, both cores; one core in brackets), Slicer = "
            "`vtkBinaryLabelmapToClosedSurfaceConversionRule.Convert` of the same label value:",
            "",
            "| segment | label | ours (s) | Slicer (s) | ours / Slicer | polygons ours / Slicer |",
            "|---|---|---|---|---|---|",
        ]
        for sgm in r["segments"]:
            lines.append(
                f"| {sgm['segment']} | {sgm['label']} | {sgm['ours_s']:.3f} "
                f"({sgm['ours_1_thread_s']:.3f}) | {sgm['slicer_s']:.3f} | {sgm['ratio']:.2f} "
                f"({sgm['ratio_1_thread']:.2f}) | {sgm['polys']} / {sgm['slicer_polys']} |")
        t = r["total"]
        lines += [
            f"| **all three** | | {t['ours_s']:.3f} ({t['ours_1_thread_s']:.3f}) | "
            f"{t['slicer_s']:.3f} | **{t['ratio']:.2f}** ({t['ratio_1_thread']:.2f}) | |",
            "",
        ]
    path.write_text("\n".join(lines))


# ---------------------------------------------------------------- main


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument(
        "--resecta", default=os.environ.get("RESECTA_BIN", str(REPO / "target/release/resecta"))
    )
    ap.add_argument(
        "--input",
        action="append",
        metavar="NAME=PATH:LABELS",
        help="label map to run (repeatable); PATH 'phantom' = `resecta phantom` demo",
    )
    ap.add_argument("--depth", type=int, default=7)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--work", default="/tmp/resecta-bench-recon", help="meshes and points")
    ap.add_argument("--out", default=None, help="folder for the results (default: here; "
                    "with --patient: docs/recon/patient-models)")
    ap.add_argument("--patient", action="store_true", help="the patient-map benchmark (#16)")
    ap.add_argument("--case", action="append", help="MSD case(s) for --patient (default 002)")
    ap.add_argument("--z-repeat", type=int, action="append",
                    help="slice repeats for --patient (default: 1 and 2)")
    args = ap.parse_args()

    rs = Resecta(args.resecta)
    log(
        f"resecta: {rs.bin} ({rs.version()}); reconstruct: {rs.reconstruct}, "
        f"measure: {rs.measure_ok}"
    )
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.patient:
        return main_patient(rs, args, work)
    inputs = DEFAULT_INPUTS
    if args.input:
        inputs = []
        for spec in args.input:
            name, rest = spec.split("=", 1)
            path, labels = rest.rsplit(":", 1)
            inputs.append((name, path, labels))

    report = {
        "date": dt.datetime.now().isoformat(timespec="seconds"),
        "commit": git_commit(),
        "resecta": rs.bin,
        "resecta_version": rs.version(),
        "depth": args.depth,
        "repeats": args.repeats,
        "machine": machine(),
        "inputs": [],
    }
    for name, path, labels in inputs:
        if path == "phantom":
            if not rs.exists:
                log(f"SKIP {name}: no resecta binary to write the phantom")
                continue
            pdir = work / "phantom"
            shutil.rmtree(pdir, ignore_errors=True)
            js, _ = rs.run_json(["phantom", "--out", str(pdir), "--json"])
            path = js["labels_file"]
        if not Path(path).is_file():
            log(f"SKIP {name}: {path} not found")
            continue
        report["inputs"].append(bench_input(name, path, labels, rs, args, work))

    out = Path(args.out or HERE)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(report, indent=1) + "\n")
    write_markdown(out / "results.md", report)
    plot(report, out / "results")
    log(f"wrote {out / 'results.json'}, results.md, results.png, results.svg")
    return 0


def main_patient(rs: Resecta, args, work: Path) -> int:
    if not (SHARED / "msd-task08-hepaticvessel").is_dir():
        log(f"SKIP: MSD cases not found under {SHARED}")
        return 0
    report = {
        "date": dt.datetime.now().isoformat(timespec="seconds"),
        "commit": git_commit(),
        "resecta": rs.bin,
        "resecta_version": rs.version(),
        "repeats": args.repeats,
        "machine": machine(),
        "patients": [
            bench_patient(rs, patient_map(case, z, work), args, work)
            for case in (args.case or ["002"])
            for z in (args.z_repeat or [1, 2])
        ],
    }
    out = Path(args.out or REPO / "docs" / "recon" / "patient-models")
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(report, indent=1) + "\n")
    write_patient_markdown(out / "results.md", report)
    log(f"wrote {out / 'results.json'}, results.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
