//! `resecta eam-study`: Paper IV's sampling study (thesis Sec. 9.2) on one atrium — a label
//! map, a mesh or the built-in phantom — with the Fig. 9.5 table beside the thesis' numbers,
//! per-condition times, the error plot and pictures of reconstructions.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::{Args, ValueEnum};
use resecta_eam::{
    EamError, MeshSplit, NoiseModel, Split, StudyAtrium, StudyConfig, StudyNormals, StudyResults,
    reconstruct_sample, run_sample, run_study,
};
use resecta_geom::{Real, TriMesh, Vec3, VoxelLimit};
use resecta_io::{MeshFormat, read_label_map, read_mesh};
use resecta_phantom::{Atrium, AtriumSpec};
use resecta_plot::{Colour, Figure, MarkerShape, MeshPanel, MeshView, Series, Style};
use resecta_recon::PoissonSolver;
use serde::Serialize;

use crate::error::CliError;
use crate::output::{counter, ms, print_json};

#[derive(Debug, Args)]
pub struct EamStudyArgs {
    /// An atrium label map (NIfTI, NRRD, MetaImage), an atrium mesh (.vtp, .vtk, .stl, .ply,
    /// .obj; closed, or open at the mitral valve and the clipped veins), or `phantom`.
    pub input: String,
    /// Folder for eam.md, eam.json, eam-error.svg/png and eam-reconstructions.png.
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Points per reconstruction.
    #[arg(long, value_delimiter = ',', default_value = "100,200,300,400,500,600")]
    pub n: Vec<usize>,
    /// Fractions of the points drawn from the upper part (the pulmonary veins' side).
    #[arg(long, value_delimiter = ',', default_value = "0.5,0.6,0.7,0.8,0.9")]
    pub u: Vec<Real>,
    /// Also reconstruct every draw with tracking noise: each point moved by |N(0.76, 0.67)| mm
    /// in a uniformly random direction (the thesis' NDI Aurora figures).
    #[arg(long)]
    pub noise: bool,
    /// Draws per condition.
    #[arg(long, default_value_t = 10)]
    pub repeats: usize,
    /// PSR depth.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=10))]
    pub depth: u32,
    /// PSR's screening weight α (> 0); values near 0 approach the unscreened PSR of 2006 that
    /// the thesis used.
    #[arg(long, default_value_t = 4.0)]
    pub screening: Real,
    /// The normals PSR gets: the reference's (the thesis) or estimated from the drawn points
    /// as for real catheter points.
    #[arg(long, value_enum, default_value_t = NormalsArg::Reference)]
    pub normals: NormalsArg,
    /// The split plane `x,y,z,nx,ny,nz` (a point and the normal towards the veins), instead
    /// of the automatic one.
    #[arg(long, value_delimiter = ',')]
    pub plane: Option<Vec<Real>>,
    /// Label-map labels of the atrial body (and appendage).
    #[arg(long, value_delimiter = ',', default_value = "36,37")]
    pub body_labels: Vec<u16>,
    /// Label-map labels of the pulmonary veins.
    #[arg(long, value_delimiter = ',', default_value = "76,77,78,79")]
    pub vein_labels: Vec<u16>,
    #[arg(long, default_value_t = 2018)]
    pub seed: u64,
    /// The machine's name, written into eam.md.
    #[arg(long)]
    pub machine: Option<String>,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum NormalsArg {
    Reference,
    Estimated,
}

/// The `--json` object: the issue's `results` rows first, then the whole study.
#[derive(Debug, Serialize)]
struct Report {
    results: Vec<Row>,
    atrium: String,
    input_kind: &'static str,
    #[serde(flatten)]
    study: StudyResults,
    /// Setting up the atrium (reading, pool, reference, split), s.
    setup_s: Real,
    files: Vec<PathBuf>,
}

#[derive(Debug, Serialize)]
struct Row {
    n: usize,
    u: Real,
    noise: bool,
    median_error_mm: Real,
    median_time_s: Real,
    /// The thesis' median for the same condition (Fig. 9.5), where it has one.
    thesis_median_error_mm: Option<Real>,
}

/// Fig. 9.5's medians for n = 100…600 (rows) × u = 0.5…0.9 (columns), without and with noise.
const THESIS: [[[Real; 5]; 6]; 2] = [
    [
        [4.30, 4.54, 4.37, 4.74, 4.61],
        [3.63, 3.61, 3.48, 3.39, 3.43],
        [3.08, 2.98, 3.11, 3.05, 3.00],
        [2.80, 2.75, 2.79, 2.80, 2.82],
        [2.67, 2.64, 2.64, 2.62, 2.56],
        [2.51, 2.44, 2.46, 2.33, 2.28],
    ],
    [
        [4.17, 4.48, 4.40, 4.67, 4.73],
        [3.63, 3.66, 3.46, 3.37, 3.47],
        [3.08, 2.98, 3.13, 3.07, 2.98],
        [2.80, 2.76, 2.80, 2.80, 2.85],
        [2.60, 2.67, 2.72, 2.60, 2.57],
        [2.51, 2.48, 2.42, 2.33, 2.30],
    ],
];

fn thesis(n: usize, u: Real, noise: bool) -> Option<Real> {
    let row = (n.is_multiple_of(100) && (100..=600).contains(&n)).then(|| n / 100 - 1)?;
    let col = (u * 10.0).round() as usize;
    ((u * 10.0 - col as Real).abs() < 1e-9 && (5..=9).contains(&col))
        .then(|| THESIS[usize::from(noise)][row][col - 5])
}

fn eam_err(e: EamError) -> CliError {
    match e {
        EamError::Recon(r) => crate::recon::recon_err(r),
        e @ (EamError::LabelsAbsent { .. }
        | EamError::NoOstia
        | EamError::NoVeinOpenings { .. }
        | EamError::EmptyPart { .. }
        | EamError::InvalidParameter { .. }
        | EamError::Phantom(_)) => CliError::BadInput(e.to_string()),
        e @ EamError::Geometry(_) => CliError::Failed(e.to_string()),
    }
}

/// The atrium of `args.input` and what kind of input it was.
fn atrium(args: &EamStudyArgs) -> Result<(StudyAtrium, &'static str), CliError> {
    let plane = match &args.plane {
        Some(v) if v.len() != 6 => {
            return Err(CliError::BadInput(format!(
                "--plane needs 6 numbers x,y,z,nx,ny,nz, got {}",
                v.len()
            )));
        }
        Some(v) => Some(
            Split::given(Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5]))
                .map_err(eam_err)?,
        ),
        None => None,
    };
    if args.input == "phantom" {
        let phantom =
            Atrium::new(&AtriumSpec::standard()).map_err(|e| CliError::Failed(e.to_string()))?;
        let mut a = StudyAtrium::from_phantom(&phantom, args.seed).map_err(eam_err)?;
        if let Some(p) = plane {
            a = a.with_split(p).map_err(eam_err)?;
        }
        return Ok((a, "phantom"));
    }
    let path = Path::new(&args.input);
    // A file stem names the atrium in reports; it is the user's own file name.
    let name = path
        .file_stem()
        .map_or_else(|| "atrium".into(), |s| s.to_string_lossy().into_owned());
    if MeshFormat::from_path(path).is_ok() {
        let mesh = read_mesh(path)?;
        let split = plane.map_or(MeshSplit::Openings, MeshSplit::Given);
        let a = StudyAtrium::from_mesh(name, &mesh, split, args.seed).map_err(eam_err)?;
        return Ok((a, "mesh"));
    }
    let labels = read_label_map(path, VoxelLimit::default())?;
    let a = StudyAtrium::from_label_map(
        name,
        &labels,
        &args.body_labels,
        &args.vein_labels,
        plane,
        args.seed,
    )
    .map_err(eam_err)?;
    Ok((a, "label map"))
}

pub fn run(args: &EamStudyArgs) -> Result<(), CliError> {
    let start = Instant::now();
    let (atrium, input_kind) = atrium(args)?;
    let setup_s = start.elapsed().as_secs_f64();
    let config = StudyConfig {
        counts: args.n.clone(),
        upper_fractions: args.u.clone(),
        noise: args.noise.then(NoiseModel::default),
        repeats: args.repeats,
        depth: args.depth,
        screening: args.screening,
        normals: match args.normals {
            NormalsArg::Reference => StudyNormals::Reference,
            NormalsArg::Estimated => StudyNormals::Estimated,
        },
        seed: args.seed,
    };
    let runs = args.n.len() * args.u.len() * args.repeats * if args.noise { 2 } else { 1 };
    let pb = counter(args.json, runs as u64, "reconstructions");
    let solver = PoissonSolver::cpu();
    let study = run_study(&atrium, &config, &solver, &|done, _| {
        pb.set_position(done as u64)
    })
    .map_err(eam_err)?;
    pb.finish_and_clear();
    let write = crate::output::files_in(&args.out_dir)?;
    let mut files = Vec::new();
    files.extend(crate::output::write_figure(
        &write,
        "eam-error",
        &error_figure(&study),
    )?);
    files.push(write(
        "eam-reconstructions.png",
        &pictures(&atrium, &config, &solver)?,
    )?);
    let results: Vec<Row> = study
        .conditions
        .iter()
        .map(|c| Row {
            n: c.n,
            u: c.u,
            noise: c.noise,
            median_error_mm: c.median_error_mm,
            median_time_s: c.median_time_s,
            thesis_median_error_mm: thesis(c.n, c.u, c.noise),
        })
        .collect();
    files.push(args.out_dir.join("eam.md"));
    files.push(args.out_dir.join("eam.json"));
    let report = Report {
        results,
        atrium: atrium.name.clone(),
        input_kind,
        study,
        setup_s,
        files,
    };
    write(
        "eam.md",
        markdown(&report, args, ms(start) / 1e3).as_bytes(),
    )?;
    let json = serde_json::to_string_pretty(&report)
        .map_err(|e| CliError::Failed(format!("JSON: {e}")))?;
    write("eam.json", format!("{json}\n").as_bytes())?;
    if args.json {
        return print_json(&report);
    }
    let best = report
        .results
        .iter()
        .filter(|r| !r.noise)
        .min_by(|a, b| a.median_error_mm.total_cmp(&b.median_error_mm));
    println!(
        "{} ({}): {} reconstructions in {:.1} s{}; tables in {}",
        report.atrium,
        input_kind,
        report.study.runs.len(),
        report.study.wall_s,
        best.map(|b| format!(
            ", best median {:.3} mm at n = {}, u = {}",
            b.median_error_mm, b.n, b.u
        ))
        .unwrap_or_default(),
        args.out_dir.join("eam.md").display()
    );
    Ok(())
}

/// Median error against n, one line per u (without noise; dashed markers with noise).
fn error_figure(r: &StudyResults) -> Figure {
    let colours = [
        Colour::BLUE,
        Colour::ORANGE,
        Colour::GREEN,
        Colour::RED,
        Colour::PURPLE,
        Colour::GREY,
        Colour::BLACK,
    ];
    let mut series = Vec::new();
    for (i, &u) in r.config.upper_fractions.iter().enumerate() {
        let colour = colours[i % colours.len()];
        for noise in [false, true] {
            let points: Vec<(Real, Real)> = r
                .conditions
                .iter()
                .filter(|c| c.u == u && c.noise == noise)
                .map(|c| (c.n as Real, c.median_error_mm))
                .collect();
            if points.is_empty() {
                continue;
            }
            series.push(if noise {
                Series::new(
                    format!("u = {u}, noise"),
                    points,
                    Style::Markers {
                        shape: MarkerShape::Triangle,
                        colour,
                    },
                )
            } else {
                Series::new(format!("u = {u}"), points, Style::Line { colour })
            });
        }
    }
    Figure {
        title: format!(
            "{}: median reference-to-PSR distance (d = {}, {} draws per point)",
            r.atrium, r.config.depth, r.config.repeats
        ),
        x_label: "points collected n".into(),
        y_label: "median error (mm)".into(),
        log_x: false,
        series,
        width: 1000,
        height: 650,
    }
}

/// A picture's vertices, triangles, overlay points and title.
type Picture = (Vec<[f64; 3]>, Vec<[u32; 3]>, Vec<[f64; 3]>, String);

/// The reference and reconstructions at n = 100, 300, 600 (those of them in the study; u = 0.8
/// where studied, as the thesis' Fig. 9.6, else the largest u), each with its points, seen from
/// behind (the veins' side).
fn pictures(
    atrium: &StudyAtrium,
    config: &StudyConfig,
    solver: &PoissonSolver,
) -> Result<Vec<u8>, CliError> {
    let ui = config
        .upper_fractions
        .iter()
        .position(|&u| (u - 0.8).abs() < 1e-9)
        .unwrap_or_else(|| {
            (0..config.upper_fractions.len())
                .max_by(|&a, &b| config.upper_fractions[a].total_cmp(&config.upper_fractions[b]))
                .unwrap_or(0)
        });
    let u = config.upper_fractions.get(ui).copied().unwrap_or(0.5);
    let mut wanted: Vec<usize> = [100, 300, 600]
        .into_iter()
        .filter(|n| config.counts.contains(n))
        .collect();
    if wanted.is_empty() {
        wanted = config.counts.iter().copied().take(3).collect();
    }
    let as_arrays =
        |m: &TriMesh| -> Vec<[f64; 3]> { m.vertices().iter().map(|v| [v.x, v.y, v.z]).collect() };
    let mut meshes: Vec<Picture> = Vec::new();
    if let Some(m) = &atrium.reference_mesh {
        meshes.push((
            as_arrays(m),
            m.triangles().to_vec(),
            Vec::new(),
            "reference".into(),
        ));
    }
    for n in wanted {
        let sample = run_sample(atrium, config, n, ui, 0, false).map_err(eam_err)?;
        let (mesh, _) = reconstruct_sample(
            &sample,
            config.depth,
            config.screening,
            config.normals,
            solver,
        )
        .map_err(eam_err)?;
        let pts = sample.positions.iter().map(|p| [p.x, p.y, p.z]).collect();
        meshes.push((
            as_arrays(&mesh),
            mesh.triangles().to_vec(),
            pts,
            format!("n = {n}, u = {u}"),
        ));
    }
    let panels: Vec<MeshPanel<'_>> = meshes
        .iter()
        .map(|(v, t, p, title)| MeshPanel {
            vertices: v,
            triangles: t,
            points: p,
            title: Some(title),
        })
        .collect();
    let mut view = MeshView::anterior(420, 420);
    view.view_dir = [0.0, 1.0, 0.0];
    view.point_radius = 1.8;
    view.title = Some(format!(
        "{}: PSR d = {} from n drawn points (dots), seen from behind",
        atrium.name, config.depth
    ));
    let columns = panels.len().min(4) as u32;
    resecta_plot::mesh_panel_png(&panels, &view, columns.max(1))
        .map_err(|e| CliError::Failed(e.to_string()))
}

fn markdown(r: &Report, args: &EamStudyArgs, total_s: Real) -> String {
    let s = &r.study;
    let c = &s.config;
    let mut o = format!(
        "# EAM sampling study: {} ({})\n\n\
         Paper IV's simulation (thesis Sec. 9.2) on one atrium: for every condition, n points \
         are drawn by area without replacement, round(n·u) of them from the upper part (the \
         pulmonary veins' side) and the rest from the lower; PSR at depth {} (screening {}) with \
         {} normals; \
         error = median distance from {} area-uniform reference points to the reconstruction. \
         {} draws per condition{}; the table gives the median over draws.\n\n",
        r.atrium,
        r.input_kind,
        c.depth,
        c.screening,
        match c.normals {
            StudyNormals::Reference => "the reference's",
            StudyNormals::Estimated => "estimated",
        },
        s.reference_points,
        c.repeats,
        if c.noise.is_some() {
            "; each draw is also reconstructed with tracking noise (every point moved by \
             |N(0.76, 0.67)| mm in a uniformly random direction)"
        } else {
            ""
        }
    );
    o.push_str(&format!(
        "- Split: `{}` — normal ({:.3}, {:.3}, {:.3}), offset {:.2} mm; upper part {:.0} mm², \
         lower {:.0} mm² ({} pool points, {:.0} % upper).\n",
        serde_json::to_string(&s.split.source).unwrap_or_default(),
        s.split.normal.x,
        s.split.normal.y,
        s.split.normal.z,
        s.split.offset,
        s.upper_area_mm2,
        s.lower_area_mm2,
        s.pool_points,
        100.0 * s.upper_area_mm2 / (s.upper_area_mm2 + s.lower_area_mm2),
    ));
    o.push_str(&format!(
        "- {} reconstructions in {:.1} s wall ({:.1} s with set-up and pictures){}; seed {}.\n\n",
        s.runs.len(),
        s.wall_s,
        total_s,
        args.machine
            .as_ref()
            .map(|m| format!(" on {m}"))
            .unwrap_or_default(),
        c.seed
    ));
    for noise in [false, true] {
        if noise && c.noise.is_none() {
            continue;
        }
        let title = format!(
            "Median error, mm ({}), ours / thesis Fig. 9.5",
            if noise { "noise" } else { "no noise" }
        );
        table(&mut o, &title, c, |n, u| {
            let ours = s
                .conditions
                .iter()
                .find(|x| x.n == n && x.u == u && x.noise == noise);
            match (ours, thesis(n, u, noise)) {
                (Some(x), Some(t)) => format!("{:.3} / {t:.2}", x.median_error_mm),
                (Some(x), None) => format!("{:.3}", x.median_error_mm),
                (None, _) => "–".into(),
            }
        });
    }
    let title = "Median time per reconstruction, ms (normals, Poisson solve, marching cubes)";
    table(&mut o, title, c, |n, u| {
        let t = s
            .conditions
            .iter()
            .find(|x| x.n == n && x.u == u && !x.noise)
            .map_or(Real::NAN, |x| x.median_time_s);
        format!("{:.1}", 1e3 * t)
    });
    o.push_str(
        "Times are measured inside the study, two reconstructions at a time on a 2-core \
         machine; the thesis' median was 600 ms per reconstruction with I/O.\n\n\
         ![median error against n](eam-error.png)\n\n\
         ![reference and reconstructions](eam-reconstructions.png)\n",
    );
    o
}

/// A Markdown section `## title` with one row per n and one column per u.
fn table(o: &mut String, title: &str, c: &StudyConfig, cell: impl Fn(usize, Real) -> String) {
    o.push_str(&format!("## {title}\n\n| n \\ u |"));
    for u in &c.upper_fractions {
        o.push_str(&format!(" {u} |"));
    }
    o.push_str("\n|---|");
    o.push_str(&"---|".repeat(c.upper_fractions.len()));
    o.push('\n');
    for &n in &c.counts {
        o.push_str(&format!("| {n} |"));
        for &u in &c.upper_fractions {
            o.push_str(&format!(" {} |", cell(n, u)));
        }
        o.push('\n');
    }
    o.push('\n');
}
