//! `resecta demo`: the main job on the embedded demo patient (a synthetic liver with analytic
//! truth). Writes it in every image format, reads each back, and measures volumes and
//! tumour–vessel clearances against the truth.

use std::path::{Path, PathBuf};
use std::time::Instant;

use resecta_geom::edt::distance_transform;
use resecta_geom::primitives::{cylinder, ellipsoid, icosphere};
use resecta_geom::{Mat3, MeshBvh, Role, TriMesh, Vec3};
use resecta_io::{Image, Segmentation};
use resecta_phantom::implicit::segment_distance;
use resecta_phantom::{Phantom, PhantomSpec, ShapeTruth, generate};
use serde::Serialize;

use crate::error::CliError;
use crate::output::{print_json, progress};
use crate::phantom::write_phantom;

/// NIfTI stores its affine in f32: ~1e-5 mm at 100 mm from the origin.
const AFFINE_TOLERANCE_MM: f64 = 1e-4;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder for the demo's files.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct RoundTrip {
    file: PathBuf,
    labels_identical: bool,
    /// Largest difference of the index→RAS affine after reading back (mm).
    max_affine_error_mm: f64,
}

#[derive(Debug, Serialize)]
struct VolumeCheck {
    role: Role,
    analytic_ml: f64,
    voxelised_ml: f64,
    relative_error: f64,
}

#[derive(Debug, Serialize)]
struct Clearance {
    tumor: String,
    vessel: String,
    /// Exact gap between the sphere and the tube surfaces.
    analytic_mm: f64,
    /// Smallest distance between voxel centres of the two labels (exact EDT).
    voxel_edt_mm: f64,
    /// Smallest distance from the tumour model's vertices to the vessel model (BVH).
    model_mm: f64,
}

#[derive(Debug, Serialize)]
struct Model {
    file: PathBuf,
    triangles: usize,
    watertight: bool,
    /// Enclosed volume of a single-solid model (not of tubes, whose parts overlap).
    volume_ml: Option<f64>,
    /// The analytic volume of the shape.
    analytic_ml: Option<f64>,
}

#[derive(Debug, Serialize)]
struct Report {
    out_dir: PathBuf,
    dims: [usize; 3],
    spacing: [f64; 3],
    voxels: usize,
    generate_ms: f64,
    round_trips: Vec<RoundTrip>,
    volumes: Vec<VolumeCheck>,
    clearances: Vec<Clearance>,
    models: Vec<Model>,
    all_round_trips_exact: bool,
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let pb = progress(args.json);
    pb.set_message("generating the demo patient");
    let start = Instant::now();
    let phantom = generate(&PhantomSpec::demo()).map_err(|e| CliError::Failed(e.to_string()))?;
    let generate_ms = start.elapsed().as_secs_f64() * 1000.0;

    pb.set_message("writing and reading back NIfTI, NRRD, .seg.nrrd, MetaImage");
    write_phantom(&args.out, "labels.nii.gz", &phantom)?;
    let round_trips = round_trips(&args.out, &phantom)?;

    pb.set_message("surface models");
    let meshes = shape_meshes(&phantom)?;
    let models = write_models(&args.out.join("models"), &meshes)?;
    pb.set_message("distance transforms");
    let clearances = clearances(&phantom, &meshes)?;
    pb.finish_and_clear();

    let grid = phantom.labels.grid();
    let report = Report {
        out_dir: args.out.clone(),
        dims: grid.dims(),
        spacing: grid.spacing(),
        voxels: grid.len(),
        generate_ms,
        all_round_trips_exact: round_trips
            .iter()
            .all(|r| r.labels_identical && r.max_affine_error_mm < AFFINE_TOLERANCE_MM),
        round_trips,
        volumes: volumes(&phantom),
        clearances,
        models,
    };
    if args.json {
        return print_json(&report);
    }
    print_report(&report);
    Ok(())
}

fn round_trips(dir: &Path, phantom: &Phantom) -> Result<Vec<RoundTrip>, CliError> {
    let labels = &phantom.labels;
    let roles = &phantom.truth.spec.roles;
    let mut out = Vec::new();
    for name in [
        "labels.nii.gz",
        "labels.nrrd",
        "labels.mha",
        "labels.seg.nrrd",
    ] {
        let file = dir.join(name);
        if name.ends_with(".seg.nrrd") {
            let mut seg = Segmentation::from_label_map(labels.clone());
            for s in &mut seg.segments {
                if let Some(role) = roles.role_of(s.label_value) {
                    s.name = role.name().to_owned();
                }
            }
            resecta_io::nrrd::write_seg_nrrd(&file, &seg)?;
        } else if name != "labels.nii.gz" {
            resecta_io::write_image(&file, &Image::from_label_map(labels))?;
        }
        let back = resecta_io::read_label_map(&file, Default::default())?;
        out.push(RoundTrip {
            labels_identical: back.data() == labels.data()
                && back.grid().dims() == labels.grid().dims(),
            max_affine_error_mm: (back.grid().affine() - labels.grid().affine()).abs().max(),
            file,
        });
    }
    Ok(out)
}

fn volumes(phantom: &Phantom) -> Vec<VolumeCheck> {
    let t = &phantom.truth;
    t.roles
        .iter()
        .map(|(&role, m)| {
            let vox = t.voxelised_mm3(role);
            VolumeCheck {
                role,
                analytic_ml: m.volume_mm3 / 1000.0,
                voxelised_ml: vox / 1000.0,
                relative_error: (vox - m.volume_mm3) / m.volume_mm3,
            }
        })
        .collect()
}

/// Subdivision level of model spheres and ellipsoids (20 480 triangles each).
const MODEL_SUBDIVISIONS: u32 = 5;

/// Analytic surface models of every shape, by shape name, with their exact volumes.
fn shape_meshes(phantom: &Phantom) -> Result<Vec<(String, TriMesh, Option<f64>)>, CliError> {
    let geom = |e: resecta_geom::GeomError| CliError::Failed(e.to_string());
    let mut out = Vec::new();
    for shape in &phantom.truth.shapes {
        let (name, mesh, exact) = match shape {
            ShapeTruth::Ellipsoid {
                name,
                center,
                radii,
                rotation,
                volume_mm3,
            } => {
                let r = Mat3::from_row_slice(rotation.as_flattened());
                let m = ellipsoid(
                    Vec3::from(*center),
                    Vec3::from(*radii),
                    r,
                    MODEL_SUBDIVISIONS,
                );
                (name, m.map_err(geom)?, Some(*volume_mm3))
            }
            ShapeTruth::Sphere {
                name,
                center,
                radius,
                volume_mm3,
            } => {
                let m = icosphere(Vec3::from(*center), *radius, MODEL_SUBDIVISIONS);
                (name, m.map_err(geom)?, Some(*volume_mm3))
            }
            ShapeTruth::Tube {
                name,
                radius,
                points,
                volume_mm3,
                ..
            } => {
                // A capsule chain: a cylinder per segment and a ball at every joint. The parts
                // overlap, so the enclosed volume of the model is not the tube's.
                let mut parts = points
                    .windows(2)
                    .map(|w| cylinder(Vec3::from(w[0]), Vec3::from(w[1]), *radius, 64, 8))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(geom)?;
                for p in points {
                    parts.push(icosphere(Vec3::from(*p), *radius, 3).map_err(geom)?);
                }
                let _ = volume_mm3;
                (name, TriMesh::concat(&parts).map_err(geom)?, None)
            }
        };
        out.push((name.clone(), mesh, exact));
    }
    Ok(out)
}

fn write_models(
    dir: &Path,
    meshes: &[(String, TriMesh, Option<f64>)],
) -> Result<Vec<Model>, CliError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| CliError::Failed(format!("{}: cannot create folder: {e}", dir.display())))?;
    let mut out = Vec::new();
    for (name, mesh, exact) in meshes {
        let file_name: String = name
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let file = dir.join(format!("{}.vtp", file_name.trim_matches('_')));
        resecta_io::write_mesh(&file, mesh)?;
        let report = mesh.report();
        out.push(Model {
            file,
            triangles: report.triangles,
            watertight: report.watertight,
            volume_ml: exact.map(|_| mesh.enclosed_volume() / 1000.0),
            analytic_ml: exact.map(|v| v / 1000.0),
        });
    }
    Ok(out)
}

/// Tumour-to-vessel clearance: exact from the shapes, from an EDT of each tumour's voxels, and
/// from the surface models.
fn clearances(
    phantom: &Phantom,
    meshes: &[(String, TriMesh, Option<f64>)],
) -> Result<Vec<Clearance>, CliError> {
    let mesh_of = |name: &str| meshes.iter().find(|(n, ..)| n == name).map(|(_, m, _)| m);
    let labels = &phantom.labels;
    let grid = labels.grid();
    let roles = &phantom.truth.spec.roles;
    let tumor_label = roles.labels(Role::Tumor).first().copied();
    let mut out = Vec::new();
    for shape in &phantom.truth.shapes {
        let ShapeTruth::Sphere {
            name,
            center,
            radius,
            ..
        } = shape
        else {
            continue;
        };
        let c = Vec3::from(*center);
        // Voxels of this tumour: tumour label and inside this sphere (tumours are disjoint).
        let mask: Vec<bool> = (0..grid.len())
            .map(|o| {
                Some(labels.data()[o]) == tumor_label
                    && (grid.voxel_center(grid.ijk(o)) - c).norm() <= *radius + 1e-9
            })
            .collect();
        let dist = distance_transform(grid, &mask).map_err(|e| CliError::Failed(e.to_string()))?;
        for vessel in &phantom.truth.shapes {
            let ShapeTruth::Tube {
                name: vname,
                role,
                radius: vr,
                points,
                ..
            } = vessel
            else {
                continue;
            };
            let analytic = points
                .windows(2)
                .map(|w| segment_distance(Vec3::from(w[0]), Vec3::from(w[1]), c, c))
                .fold(f64::INFINITY, f64::min)
                - radius
                - vr;
            let vlabels = roles.labels(*role);
            let voxel_edt_mm = labels
                .data()
                .iter()
                .zip(dist.data())
                .filter(|(l, _)| vlabels.contains(l))
                .map(|(_, &d)| f64::from(d))
                .fold(f64::INFINITY, f64::min);
            let model_mm = match (mesh_of(name), mesh_of(vname)) {
                (Some(t), Some(v)) => {
                    let bvh = MeshBvh::new(v).map_err(|e| CliError::Failed(e.to_string()))?;
                    bvh.closest_points(t.vertices())
                        .into_iter()
                        .flatten()
                        .map(|c| c.distance)
                        .fold(f64::INFINITY, f64::min)
                }
                _ => f64::NAN,
            };
            out.push(Clearance {
                tumor: name.clone(),
                vessel: vname.clone(),
                analytic_mm: analytic,
                voxel_edt_mm,
                model_mm,
            });
        }
    }
    Ok(out)
}

fn print_report(r: &Report) {
    println!(
        "demo patient: {} × {} × {} voxels of {:.2} × {:.2} × {:.2} mm (oblique), generated in {:.0} ms",
        r.dims[0], r.dims[1], r.dims[2], r.spacing[0], r.spacing[1], r.spacing[2], r.generate_ms
    );
    println!("files in {}:", r.out_dir.display());
    for t in &r.round_trips {
        println!(
            "  {:<28} read back {}  (affine error {:.1e} mm)",
            t.file.display(),
            if t.labels_identical {
                "identical"
            } else {
                "DIFFERENT"
            },
            t.max_affine_error_mm
        );
    }
    println!("volumes (voxel centres vs analytic truth):");
    for v in &r.volumes {
        println!(
            "  {:<10} {:>9.3} ml voxelised, {:>9.3} ml analytic ({:+.2} %)",
            v.role.name(),
            v.voxelised_ml,
            v.analytic_ml,
            100.0 * v.relative_error
        );
    }
    println!("tumour–vessel clearance (voxel EDT, surface models, exact):");
    for c in &r.clearances {
        println!(
            "  {:<10} – {:<10} {:>7.2} mm EDT, {:>7.2} mm models, {:>7.2} mm exact",
            c.tumor, c.vessel, c.voxel_edt_mm, c.model_mm, c.analytic_mm
        );
    }
    println!("surface models (RAS, .vtp):");
    for m in &r.models {
        let volume = match (m.volume_ml, m.analytic_ml) {
            (Some(v), Some(a)) => format!(", {v:>9.3} ml (analytic {a:.3} ml)"),
            _ => String::new(),
        };
        println!(
            "  {:<36} {:>6} triangles, watertight {}{volume}",
            m.file.display(),
            m.triangles,
            m.watertight
        );
    }
}
