//! `resecta info FILE`: geometry and content of an image, segmentation or mesh file.

use std::path::{Path, PathBuf};

use resecta_geom::{Grid, MeshReport, TriMesh, VoxelLimit};
use resecta_io::{Image, ImageFormat, IoError, MeshFormat, Segmentation};
use serde::Serialize;

use crate::error::CliError;
use crate::output::print_json;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Image (.nii, .nii.gz, .nrrd, .nhdr, .seg.nrrd, .mha, .mhd) or mesh (.vtk, .vtp, .stl, .ply, .obj).
    pub file: PathBuf,
    /// Refuse images with more voxels than this.
    #[arg(long, default_value_t = VoxelLimit::default().0)]
    pub max_voxels: u64,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Integer images with more distinct values than this are reported by range only (a CT, say).
const MAX_LISTED_LABELS: usize = 1024;

#[derive(Debug, Serialize)]
struct GridInfo {
    dims: [usize; 3],
    spacing: [f64; 3],
    origin: [f64; 3],
    /// Rows of the 3×3 direction matrix (columns are the i, j, k axes in RAS).
    direction: [[f64; 3]; 3],
    /// Rows of the 4×4 index→RAS affine.
    affine: [[f64; 4]; 4],
    voxel_volume_mm3: f64,
}

impl From<&Grid> for GridInfo {
    fn from(g: &Grid) -> Self {
        let d = g.direction();
        let a = g.affine();
        Self {
            dims: g.dims(),
            spacing: g.spacing(),
            origin: g.origin().into(),
            direction: std::array::from_fn(|r| std::array::from_fn(|c| d[(r, c)])),
            affine: std::array::from_fn(|r| std::array::from_fn(|c| a[(r, c)])),
            voxel_volume_mm3: g.voxel_volume_mm3(),
        }
    }
}

#[derive(Debug, Serialize)]
struct LabelInfo {
    value: u16,
    voxels: u64,
    ml: f64,
}

#[derive(Debug, Serialize)]
struct SegmentInfo {
    name: String,
    label_value: u16,
    layer: usize,
    voxels: u64,
    ml: f64,
}

#[derive(Debug, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
enum Info {
    Image {
        file: PathBuf,
        format: &'static str,
        #[serde(flatten)]
        grid: GridInfo,
        scalar_type: String,
        value_range: Option<[f64; 2]>,
        /// Non-zero integer values with counts; `null` for float or many-valued images.
        labels: Option<Vec<LabelInfo>>,
    },
    Segmentation {
        file: PathBuf,
        format: &'static str,
        #[serde(flatten)]
        grid: GridInfo,
        layers: usize,
        segments: Vec<SegmentInfo>,
    },
    Mesh {
        file: PathBuf,
        format: &'static str,
        #[serde(flatten)]
        report: MeshReport,
        area_mm2: f64,
        /// Enclosed volume, for watertight meshes.
        volume_ml: Option<f64>,
        bounds: Option<[[f64; 3]; 2]>,
        normals: bool,
        scalars: Vec<String>,
    },
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let info = describe(&args.file, VoxelLimit(args.max_voxels))?;
    if args.json {
        return print_json(&info);
    }
    print_human(&info);
    Ok(())
}

fn describe(path: &Path, limit: VoxelLimit) -> Result<Info, CliError> {
    let file = path.to_path_buf();
    if let Ok(format) = MeshFormat::from_path(path) {
        let mesh = resecta_io::read_mesh(path)?;
        return Ok(mesh_info(file, format.extension(), &mesh));
    }
    let format = ImageFormat::from_path(path).map_err(|_| {
        IoError::new(
            path,
            resecta_io::ErrorKind::UnknownFormat(
                path.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                ".nii, .nii.gz, .nrrd, .nhdr, .seg.nrrd, .mha, .mhd, .vtk, .vtp, .stl, .ply, .obj",
            ),
        )
    })?;
    if format == ImageFormat::SegNrrd {
        let seg = resecta_io::nrrd::read_seg_nrrd(path, limit)?;
        return Ok(segmentation_info(file, &seg));
    }
    let image = resecta_io::read_image(path, limit)?;
    Ok(image_info(file, format_name(format), &image))
}

fn format_name(f: ImageFormat) -> &'static str {
    match f {
        ImageFormat::Nifti { .. } => "nifti",
        ImageFormat::Nrrd { .. } => "nrrd",
        ImageFormat::SegNrrd => "seg.nrrd",
        ImageFormat::MetaImage { .. } => "metaimage",
    }
}

fn image_info(file: PathBuf, format: &'static str, image: &Image) -> Info {
    let grid = image.grid();
    let ml_per_voxel = grid.voxel_volume_mm3() / 1000.0;
    let labels = image
        .to_label_map()
        .ok()
        .map(|l| l.value_counts())
        .and_then(|counts| {
            (counts.len() <= MAX_LISTED_LABELS).then(|| {
                counts
                    .into_iter()
                    .filter(|&(v, _)| v != 0)
                    .map(|(value, voxels)| LabelInfo {
                        value,
                        voxels,
                        ml: voxels as f64 * ml_per_voxel,
                    })
                    .collect()
            })
        });
    Info::Image {
        file,
        format,
        grid: grid.into(),
        scalar_type: format!("{:?}", image.data().scalar_type()).to_lowercase(),
        value_range: image.value_range().map(|(lo, hi)| [lo, hi]),
        labels,
    }
}

fn segmentation_info(file: PathBuf, seg: &Segmentation) -> Info {
    let ml_per_voxel = seg.grid.voxel_volume_mm3() / 1000.0;
    let counts: Vec<_> = seg
        .layers
        .iter()
        .map(resecta_geom::Volume::value_counts)
        .collect();
    let segments = seg
        .segments
        .iter()
        .map(|s| {
            let voxels = counts
                .get(s.layer)
                .and_then(|c| c.get(&s.label_value))
                .copied()
                .unwrap_or(0);
            SegmentInfo {
                name: s.name.clone(),
                label_value: s.label_value,
                layer: s.layer,
                voxels,
                ml: voxels as f64 * ml_per_voxel,
            }
        })
        .collect();
    Info::Segmentation {
        file,
        format: "seg.nrrd",
        grid: (&seg.grid).into(),
        layers: seg.layers.len(),
        segments,
    }
}

fn mesh_info(file: PathBuf, format: &'static str, mesh: &TriMesh) -> Info {
    let report = mesh.report();
    Info::Mesh {
        file,
        format,
        volume_ml: report.watertight.then(|| mesh.enclosed_volume() / 1000.0),
        report,
        area_mm2: mesh.area(),
        bounds: mesh.bounds().map(|(lo, hi)| [lo.into(), hi.into()]),
        normals: mesh.normals().is_some(),
        scalars: mesh.scalars().keys().cloned().collect(),
    }
}

fn print_human(info: &Info) {
    let grid_lines = |g: &GridInfo| {
        println!("  dims      {} × {} × {}", g.dims[0], g.dims[1], g.dims[2]);
        println!(
            "  spacing   {:.4} × {:.4} × {:.4} mm",
            g.spacing[0], g.spacing[1], g.spacing[2]
        );
        println!(
            "  origin    ({:.3}, {:.3}, {:.3}) mm RAS",
            g.origin[0], g.origin[1], g.origin[2]
        );
        for (r, row) in g.direction.iter().enumerate() {
            let head = if r == 0 { "  direction" } else { "           " };
            println!("{head} [{:+.6} {:+.6} {:+.6}]", row[0], row[1], row[2]);
        }
    };
    match info {
        Info::Image {
            file,
            format,
            grid,
            scalar_type,
            value_range,
            labels,
        } => {
            println!("{} ({format} image, {scalar_type})", file.display());
            grid_lines(grid);
            if let Some([lo, hi]) = value_range {
                println!("  values    {lo} … {hi}");
            }
            for l in labels.iter().flatten() {
                println!(
                    "  label {:>5}  {:>10} voxels  {:>10.2} ml",
                    l.value, l.voxels, l.ml
                );
            }
        }
        Info::Segmentation {
            file,
            grid,
            layers,
            segments,
            ..
        } => {
            println!(
                "{} (Slicer segmentation, {layers} layer(s))",
                file.display()
            );
            grid_lines(grid);
            for s in segments {
                println!(
                    "  segment {:<24} layer {} value {:>3}  {:>10} voxels  {:>10.2} ml",
                    s.name, s.layer, s.label_value, s.voxels, s.ml
                );
            }
        }
        Info::Mesh {
            file,
            format,
            report,
            area_mm2,
            volume_ml,
            ..
        } => {
            println!("{} ({format} mesh)", file.display());
            println!(
                "  {} vertices, {} triangles",
                report.vertices, report.triangles
            );
            println!(
                "  watertight {}  (boundary edges {}, non-manifold {}, inconsistent {}, degenerate {})",
                report.watertight,
                report.boundary_edges,
                report.non_manifold_edges,
                report.inconsistent_edges,
                report.degenerate_triangles
            );
            println!("  area      {area_mm2:.2} mm²");
            if let Some(v) = volume_ml {
                println!("  volume    {v:.3} ml");
            }
        }
    }
}
