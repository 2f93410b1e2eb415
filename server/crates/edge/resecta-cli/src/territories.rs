//! `resecta territories`: the vessel trees of a label map's portal, hepatic and other vessel
//! labels (`resecta-vessels`), and the vascular territories of the functional liver each tree's
//! branches feed or drain.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use resecta_geom::{LabelMap, Real, Role, RoleMap, Vec3, Volume, VoxelLimit};
use resecta_io::{PolylineSet, read_label_map, write_label_map, write_polylines};
use resecta_vessels::{
    BranchSelection, RootChoice, TerritoryParams, VesselParams, VesselSystem, VesselTree,
    territories, vessel_tree,
};
use serde::Serialize;

use crate::error::CliError;
use crate::output::{ms, print_json, progress};

/// The vessel systems a label map may hold, by role, with how their trees are rooted (a vessel
/// label not split into portal and hepatic: at its widest end).
const SYSTEMS: [(Role, &str, Option<VesselSystem>); 3] = [
    (Role::Portal, "portal", Some(VesselSystem::Portal)),
    (Role::Hepatic, "hepatic", Some(VesselSystem::Hepatic)),
    (Role::Vessel, "vessel", None),
];

/// Territories of the Couinaud-style grouping (`--couinaud`).
const COUINAUD_BRANCHES: usize = 8;

#[derive(Debug, Args)]
pub struct TerritoriesArgs {
    /// Label map (NIfTI, NRRD, .seg.nrrd, MetaImage).
    pub labelmap: PathBuf,
    /// Role map as JSON (as in plan files); default `{"parenchyma":[1],"tumor":[2],"portal":[3],
    /// "hepatic":[4]}`.
    #[arg(long)]
    pub roles: Option<String>,
    /// Territories of every branch of this generation (1: the vessels leaving the root), and of
    /// vessels that end sooner.
    #[arg(long, default_value_t = 2, conflicts_with_all = ["branches", "couinaud"])]
    pub order: u32,
    /// A system's root given by a point instead of found (the end of its widest terminal
    /// branch): `SYSTEM=x,y,z` (RAS mm), the tree's node nearest it; repeat per system. For
    /// labels where the widest end is not the root (e.g. a portal label holding the splenic vein).
    #[arg(long, value_parser = parse_root, allow_hyphen_values = true)]
    pub root: Vec<(String, [Real; 3])>,
    /// Portal territories grouped Couinaud-style: the eight largest portal subtrees (the
    /// longest centrelines split first). An approximation of the eight segments from the tree's
    /// shape, not an anatomical labelling of segments I–VIII; other systems keep `--order`.
    #[arg(long, conflicts_with = "branches")]
    pub couinaud: bool,
    /// Explicit branches per system, by edge id: `{"portal":[3,4],"hepatic":[1]}`.
    #[arg(long)]
    pub branches: Option<String>,
    /// A liver mask (non-zero = liver) on the label map's grid, for label maps without a liver
    /// label (the MSD hepatic-vessel cases): the functional liver is its voxels but tumour ones.
    #[arg(long)]
    pub liver_mask: Option<PathBuf>,
    /// Write the territory label maps (NIfTI), the centrelines (VTP) and the report here.
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct TerritoryReport {
    /// 1-based label of the territory in its system's label map.
    id: usize,
    vessel: &'static str,
    /// The edge heading the branch; `None` for the proximal territory (the trunk above every
    /// selected branch).
    branch: Option<usize>,
    ml: Real,
}

#[derive(Debug, Serialize)]
struct SystemReport {
    vessel: &'static str,
    /// How the territories were chosen.
    grouping: String,
    root: [Real; 3],
    /// Trees (more than one for hepatic veins entering the vena cava separately).
    roots: usize,
    edges: usize,
    branch_points: usize,
    specks: usize,
    speck_voxels: usize,
    gaps_bridged: usize,
    detached_components: usize,
    detached_voxels: usize,
    loop_edges_dropped: usize,
    territory_map: String,
    centrelines: String,
}

#[derive(Debug, Serialize)]
struct Report {
    liver_ml: Real,
    territories: Vec<TerritoryReport>,
    systems: Vec<SystemReport>,
    elapsed_ms: Real,
}

fn bad(e: impl std::fmt::Display) -> CliError {
    CliError::BadInput(e.to_string())
}

fn mask(labels: &LabelMap, keep: impl Fn(u16) -> bool) -> Result<Volume<bool>, CliError> {
    let data = labels.data().iter().map(|&l| keep(l)).collect();
    Volume::from_vec(labels.grid().clone(), data).map_err(bad)
}

/// The functional liver of `--liver-mask`: its voxels but the label map's tumour ones. The
/// mask must lie on the label map's grid (dimensions equal, corners within 0.01 mm).
fn masked_liver(labels: &LabelMap, roles: &RoleMap, path: &Path) -> Result<Volume<bool>, CliError> {
    let m = read_label_map(path, VoxelLimit::default())?;
    let (a, b) = (labels.grid(), m.grid());
    let [nx, ny, nz] = a.dims();
    let same = a.dims() == b.dims()
        && [
            [0, 0, 0],
            [nx - 1, ny - 1, nz - 1],
            [nx - 1, 0, 0],
            [0, ny - 1, nz - 1],
        ]
        .iter()
        .all(|&ijk| (a.voxel_center(ijk) - b.voxel_center(ijk)).norm() < 0.01);
    if !same {
        return Err(bad(format!(
            "{}: its grid differs from the label map's",
            path.display()
        )));
    }
    let tumour = roles.labels(Role::Tumor);
    let data = m
        .data()
        .iter()
        .zip(labels.data())
        .map(|(&v, l)| v != 0 && !tumour.contains(l))
        .collect();
    Volume::from_vec(a.clone(), data).map_err(bad)
}

fn parse_root(s: &str) -> Result<(String, [Real; 3]), String> {
    let (system, point) = s
        .split_once('=')
        .ok_or_else(|| format!("expected SYSTEM=x,y,z, got {s:?}"))?;
    if !SYSTEMS.iter().any(|(_, n, _)| *n == system) {
        return Err(format!(
            "{system:?} is not a vessel system (portal, hepatic, vessel)"
        ));
    }
    Ok((system.to_owned(), crate::plan::parse_point(point)?))
}

/// The branches `--branches` names for `system`, the Couinaud-style grouping, or the
/// generation rule.
fn selection(args: &TerritoriesArgs, system: &str) -> Result<BranchSelection, CliError> {
    let Some(text) = &args.branches else {
        if args.couinaud && system == "portal" {
            return Ok(BranchSelection::Largest(COUINAUD_BRANCHES));
        }
        return Ok(BranchSelection::Generation(args.order));
    };
    let map: std::collections::BTreeMap<String, Vec<usize>> =
        serde_json::from_str(text).map_err(|e| bad(format!("--branches: {e}")))?;
    if let Some(k) = map.keys().find(|k| !SYSTEMS.iter().any(|(_, s, _)| s == k)) {
        return Err(bad(format!(
            "--branches: {k:?} is not a vessel system (portal, hepatic, vessel)"
        )));
    }
    Ok(BranchSelection::Ids(
        map.get(system).cloned().unwrap_or_default(),
    ))
}

/// The tree's centrelines with their radius per point and branch id and generation per line.
fn centrelines(tree: &VesselTree) -> PolylineSet {
    let mut set = PolylineSet::default();
    let (mut radius, mut id, mut generation) = (Vec::new(), Vec::new(), Vec::new());
    for e in &tree.edges {
        set.lines.push(e.points.clone());
        radius.extend_from_slice(&e.radii);
        id.push(e.id as Real);
        generation.push(Real::from(e.generation));
    }
    set.point_data.push(("radius".into(), radius));
    set.cell_data.push(("branch".into(), id));
    set.cell_data.push(("generation".into(), generation));
    set
}

fn arr(v: Vec3) -> [Real; 3] {
    [v.x, v.y, v.z]
}

pub fn run(args: &TerritoriesArgs) -> Result<(), CliError> {
    let t0 = Instant::now();
    let pb = progress(args.json);
    pb.set_message("reading the label map");
    let labels = read_label_map(&args.labelmap, VoxelLimit::default())?;
    let roles: RoleMap = match &args.roles {
        Some(s) => serde_json::from_str(s).map_err(|e| bad(format!("--roles: {e}")))?,
        None => RoleMap::default(),
    };
    let liver = match &args.liver_mask {
        Some(path) => masked_liver(&labels, &roles, path)?,
        None => mask(&labels, |l| {
            roles.role_of(l).is_some_and(Role::is_functional_liver)
        })?,
    };
    if !liver.data().iter().any(|&v| v) {
        return Err(bad(format!(
            "{}: no functional liver (no label of a non-tumour role occurs)",
            args.labelmap.display()
        )));
    }
    std::fs::create_dir_all(&args.out_dir)
        .map_err(|e| CliError::Failed(format!("{}: {e}", args.out_dir.display())))?;
    let mut report = Report {
        liver_ml: 0.0,
        territories: Vec::new(),
        systems: Vec::new(),
        elapsed_ms: 0.0,
    };
    for (role, name, system) in SYSTEMS {
        let ids = roles.labels(role);
        let vessels = mask(&labels, |l| ids.contains(&l))?;
        if ids.is_empty() || !vessels.data().iter().any(|&v| v) {
            continue;
        }
        pb.set_message(format!("{name}: centrelines"));
        let named = |e: resecta_vessels::VesselError| bad(format!("{name} vessels: {e}"));
        let root = match args.root.iter().find(|(s, _)| s == name) {
            Some((_, p)) => RootChoice::NearestTo(Vec3::from(*p)),
            None => system.map_or(RootChoice::Auto, VesselSystem::root_choice),
        };
        let tree = vessel_tree(&vessels, root, &VesselParams::default()).map_err(named)?;
        pb.set_message(format!("{name}: territories"));
        let sel = selection(args, name)?;
        let grouping = match &sel {
            BranchSelection::Largest(k) => format!(
                "couinaud-style: the {k} largest portal subtrees (an approximation, not segments I-VIII)"
            ),
            BranchSelection::Generation(k) => format!("generation {k}"),
            BranchSelection::Ids(_) => "branches given".to_owned(),
        };
        let t = territories(&tree, &liver, &sel, &TerritoryParams::default()).map_err(named)?;
        let wide: Vec<u16> = t
            .labels
            .data()
            .iter()
            .map(|&l| u16::try_from(l).map_err(|_| bad(format!("{name}: over 65535 territories"))))
            .collect::<Result<_, _>>()?;
        let map_path = args.out_dir.join(format!("{name}-territories.nii.gz"));
        write_label_map(
            &map_path,
            &Volume::from_vec(t.labels.grid().clone(), wide).map_err(bad)?,
        )?;
        let lines_path = args.out_dir.join(format!("{name}-centrelines.vtp"));
        write_polylines(&lines_path, &centrelines(&tree))?;
        report.liver_ml = t.liver_ml;
        report.territories.extend(
            t.territories
                .iter()
                .enumerate()
                .map(|(k, x)| TerritoryReport {
                    id: k + 1,
                    vessel: name,
                    branch: x.branch,
                    ml: x.volume_ml,
                }),
        );
        let r = &tree.report;
        report.systems.push(SystemReport {
            vessel: name,
            grouping,
            root: arr(tree.nodes[tree.root].position),
            roots: tree.roots.len(),
            edges: tree.edges.len(),
            branch_points: tree
                .nodes
                .iter()
                .filter(|n| n.kind == resecta_vessels::NodeKind::Branch)
                .count(),
            specks: r.specks,
            speck_voxels: r.speck_voxels,
            gaps_bridged: r.gaps_bridged,
            detached_components: r.detached_components,
            detached_voxels: r.detached_voxels,
            loop_edges_dropped: r.loop_edges_dropped,
            territory_map: display(&map_path),
            centrelines: display(&lines_path),
        });
    }
    if report.systems.is_empty() {
        return Err(bad(format!(
            "{}: no vessel label of the role map (portal, hepatic, vessel) occurs",
            args.labelmap.display()
        )));
    }
    report.elapsed_ms = ms(t0);
    let text =
        serde_json::to_string_pretty(&report).map_err(|e| CliError::Failed(e.to_string()))?;
    let path = args.out_dir.join("territories.json");
    std::fs::write(&path, text)
        .map_err(|e| CliError::Failed(format!("{}: {e}", path.display())))?;
    pb.finish_and_clear();
    if args.json {
        return print_json(&report);
    }
    println!("functional liver {:.1} ml", report.liver_ml);
    for s in &report.systems {
        println!(
            "{}: {} branches, {} branch points, {} specks dropped, {} gaps bridged, {} detached pieces",
            s.vessel, s.edges, s.branch_points, s.specks, s.gaps_bridged, s.detached_components
        );
    }
    for t in &report.territories {
        let what = t
            .branch
            .map_or_else(|| "proximal".to_owned(), |b| format!("branch {b}"));
        println!("  {} territory {} ({what}): {:.1} ml", t.vessel, t.id, t.ml);
    }
    Ok(())
}

fn display(p: &Path) -> String {
    p.display().to_string()
}
