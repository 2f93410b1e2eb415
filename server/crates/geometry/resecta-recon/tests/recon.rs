//! Reconstruction against analytic shapes on oblique anisotropic grids, the patient model of a
//! phantom, the study and bad input (real label maps: tests/test_reconstruct.py).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use resecta_geom::{Grid, LabelMap, Mat3, Real, Role, RoleMap, TriMesh, Vec3, Volume};
use resecta_phantom::{PhantomSpec, generate};
use resecta_recon::study::{StudyConfig, auto_depth, run};
use resecta_recon::{
    McsdParams, ModelOptions, ParenchymaMethod, ReconError, mask, mcsd, patient_models, psr,
};

const CENTRE: Vec3 = Vec3::new(3.0, -4.0, 7.0);
const RADIUS: Real = 30.0;

/// A ball of radius 30 mm voxelised at centres on an oblique 1.1 × 0.9 × 1.6 mm grid.
fn ball() -> Volume<bool> {
    let dir = nalgebra::Rotation3::from_euler_angles(0.2, -0.15, 0.4).into_inner();
    let dims = [80, 96, 56];
    let spacing = [1.1, 0.9, 1.6];
    let lin: Mat3 = dir * Mat3::from_diagonal(&Vec3::from(spacing));
    let half = Vec3::new(dims[0] as Real, dims[1] as Real, dims[2] as Real) * 0.5;
    let origin = CENTRE - lin * half;
    let grid = Grid::new(dims, spacing, origin, dir).unwrap();
    let mut data = Vec::with_capacity(grid.len());
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                data.push((grid.voxel_center([i, j, k]) - CENTRE).norm() <= RADIUS);
            }
        }
    }
    Volume::from_vec(grid, data).unwrap()
}

fn mask_mm3(m: &Volume<bool>) -> Real {
    m.data().iter().filter(|&&b| b).count() as Real * m.grid().voxel_volume_mm3()
}

/// Mean and max distance of the mesh's vertices to the analytic sphere.
fn sphere_error(mesh: &TriMesh) -> (Real, Real) {
    let d: Vec<Real> = mesh
        .vertices()
        .iter()
        .map(|v| ((v - CENTRE).norm() - RADIUS).abs())
        .collect();
    (
        d.iter().sum::<Real>() / d.len() as Real,
        d.iter().copied().fold(0.0, Real::max),
    )
}

#[test]
fn psr_of_an_oblique_ball_is_accurate_closed_and_volume_true() {
    let m = ball();
    let model = psr::reconstruct(&m, 7).unwrap();
    let report = model.mesh.report();
    assert!(report.watertight, "{report:?}");
    let (mean, max) = sphere_error(&model.mesh);
    // Cells of 1.1 × 60 mm / 128 ≈ 0.55 mm; voxels up to 1.6 mm.
    assert!(mean < 0.25 && max < 1.0, "mean {mean} max {max}");
    let vol = model.mesh.signed_volume();
    let voxels = mask_mm3(&m);
    assert!(vol > 0.0);
    assert!(
        (vol - voxels).abs() / voxels < 0.005,
        "PSR {vol} vs mask {voxels}"
    );
    assert_eq!(
        model.mesh.normals().map(<[Vec3]>::len),
        Some(model.mesh.vertices().len())
    );
}

#[test]
fn mcsd_of_an_oblique_ball_is_closed_and_close() {
    let m = ball();
    let mesh = mcsd::reconstruct(&m, &McsdParams::default()).unwrap();
    assert!(mesh.report().watertight);
    let (mean, max) = sphere_error(&mesh);
    assert!(mean < 0.5 && max < 1.5, "mean {mean} max {max}");
    let exact = 4.0 / 3.0 * std::f64::consts::PI * RADIUS.powi(3);
    let rel = (mesh.signed_volume() - exact) / exact;
    assert!(rel.abs() < 0.03, "volume off by {rel}");
    // Decimation keeps it closed and removes the requested share.
    let coarse = mcsd::reconstruct(
        &m,
        &McsdParams {
            smoothing: 0.5,
            decimation: 0.5,
        },
    )
    .unwrap();
    assert!(coarse.report().watertight);
    let ratio = coarse.triangles().len() as Real / mesh.triangles().len() as Real;
    assert!((ratio - 0.5).abs() < 0.03, "ratio {ratio}");
}

#[test]
fn psr_is_deterministic() {
    let m = ball();
    let a = psr::reconstruct(&m, 6).unwrap();
    let b = psr::reconstruct(&m, 6).unwrap();
    assert_eq!(a.mesh, b.mesh);
}

#[test]
fn auto_depth_picks_a_middle_depth() {
    let m = ball();
    let points = psr::points(&m).unwrap();
    let auto = auto_depth(&points, &[5, 6, 7, 8]).unwrap();
    assert_eq!(auto.candidates.len(), 4);
    assert!((6..=7).contains(&auto.depth), "picked {}", auto.depth);
    let best = auto
        .candidates
        .iter()
        .map(|c| c.sigma)
        .fold(Real::INFINITY, Real::min);
    let chosen = auto
        .candidates
        .iter()
        .find(|c| c.depth == auto.depth)
        .unwrap();
    assert_eq!(chosen.sigma, best);
}

#[test]
fn border_touching_and_tiny_masks() {
    // A slab filling the whole volume in x and y: closed models anyway.
    let grid = Grid::axis_aligned([20, 20, 10], [1.0, 1.0, 2.0], Vec3::zeros()).unwrap();
    let data = (0..grid.len()).map(|o| grid.ijk(o)[2] < 6).collect();
    let slab = Volume::from_vec(grid.clone(), data).unwrap();
    assert!(
        mcsd::reconstruct(&slab, &McsdParams::default())
            .unwrap()
            .report()
            .watertight
    );
    let model = psr::reconstruct(&slab, 6).unwrap();
    assert!(model.mesh.report().watertight);
    // One voxel: MCSD gives a closed octahedron-like surface.
    let mut one = Volume::filled(grid, false);
    one.set([5, 5, 5], true);
    assert!(
        mcsd::reconstruct(&one, &McsdParams::default())
            .unwrap()
            .report()
            .watertight
    );
    // And PSR either refuses it clearly or closes it.
    match psr::reconstruct(&one, 5) {
        Ok(m) => assert!(m.mesh.report().watertight),
        Err(e) => assert!(matches!(e, ReconError::Poisson(_)), "{e}"),
    }
}

#[test]
fn bad_input_is_refused() {
    let grid = Grid::axis_aligned([4, 4, 4], [1.0; 3], Vec3::zeros()).unwrap();
    let labels: LabelMap = Volume::filled(grid.clone(), 0u16);
    assert!(matches!(
        mask::select(&labels, &[]),
        Err(ReconError::NoLabels)
    ));
    assert!(matches!(
        mask::select(&labels, &[3, 7]),
        Err(ReconError::LabelsAbsent { labels }) if labels == vec![3, 7]
    ));
    assert!(matches!(
        mask::select_cropped(&labels, &[7, 3], 1),
        Err(ReconError::LabelsAbsent { labels }) if labels == vec![3, 7]
    ));
    let empty = Volume::filled(grid, false);
    assert!(matches!(
        psr::reconstruct(&empty, 7),
        Err(ReconError::EmptyMask)
    ));
    assert!(matches!(
        mcsd::reconstruct(
            &ball(),
            &McsdParams {
                smoothing: 1.5,
                decimation: 0.0
            }
        ),
        Err(ReconError::InvalidParameter {
            name: "smoothing",
            ..
        })
    ));
    for depth in [0, 11] {
        assert!(matches!(
            psr::reconstruct(&ball(), depth),
            Err(ReconError::Poisson(_))
        ));
    }
}

#[test]
fn a_cropped_selection_is_the_crop_of_the_selection() {
    let grid = Grid::new(
        [20, 16, 12],
        [1.1, 0.9, 1.6],
        Vec3::new(-3.0, 2.0, 5.0),
        nalgebra::Rotation3::from_euler_angles(0.2, -0.1, 0.3).into_inner(),
    )
    .unwrap();
    let data = (0..grid.len())
        .map(|o| {
            let [i, j, k] = grid.ijk(o);
            ((i * 7 + j * 3 + k * 5) % 11 % 4) as u16 * u16::from((3..15).contains(&i) && j > 2)
        })
        .collect();
    let labels: LabelMap = Volume::from_vec(grid, data).unwrap();
    for wanted in [&[2u16][..], &[1, 3]] {
        for pad in [0, 1, 2] {
            let direct = mask::select_cropped(&labels, wanted, pad).unwrap();
            let full = mask::crop(&mask::select(&labels, wanted).unwrap(), pad).unwrap();
            assert_eq!(direct.grid(), full.grid());
            assert_eq!(direct.data(), full.data());
        }
    }
}

#[test]
fn components_are_split_largest_first() {
    let grid = Grid::axis_aligned([12, 6, 6], [1.0; 3], Vec3::zeros()).unwrap();
    let data = (0..grid.len())
        .map(|o| {
            let [i, j, k] = grid.ijk(o);
            (1..=4).contains(&j) && (1..=4).contains(&k) && (i == 1 || (4..=9).contains(&i))
        })
        .collect();
    let m = Volume::from_vec(grid, data).unwrap();
    let parts = mask::components(&m).unwrap();
    let sizes: Vec<usize> = parts
        .iter()
        .map(|p| p.data().iter().filter(|&&b| b).count())
        .collect();
    assert_eq!(sizes, vec![96, 16]);
    // Cropped with a margin, in the right place.
    assert_eq!(parts[1].grid().dims(), [3, 6, 6]);
    assert_eq!(parts[1].grid().origin(), Vec3::new(0.0, 0.0, 0.0));
}

#[test]
fn patient_model_of_the_small_phantom() {
    let phantom = generate(&PhantomSpec::small()).unwrap();
    let roles = RoleMap::default();
    let mut names = Vec::new();
    let models = patient_models(
        &phantom.labels,
        &roles,
        &ModelOptions::default(),
        &mut |n| {
            names.push(n.to_owned());
            true
        },
    )
    .unwrap()
    .models;
    let by_role = |r: Role| models.iter().filter(|m| m.role == r).count();
    assert_eq!(by_role(Role::Parenchyma), 1);
    assert_eq!(by_role(Role::Tumor), 1);
    assert_eq!(by_role(Role::Portal), 1);
    assert_eq!(names.len(), models.len());
    // Cancelling after the first model stops the work.
    let cancelled = patient_models(
        &phantom.labels,
        &roles,
        &ModelOptions::default(),
        &mut |_| false,
    );
    assert!(matches!(
        cancelled,
        Err(resecta_recon::ReconError::Cancelled)
    ));
    for m in &models {
        assert!(m.mesh.report().watertight, "{}", m.name());
        assert!(m.mesh.signed_volume() > 0.0);
    }
    // The liver model encloses the whole liver (tumour and inner vessels included): compare with
    // the analytic ellipsoid volume.
    assert_eq!(models[0].method, "psr");
    let liver = &models[0].mesh;
    let truth = phantom.truth.liver.volume_mm3;
    assert!((liver.signed_volume() - truth).abs() / truth < 0.03);
    // The tumour against its voxelised volume. MCSD (as Slicer's) cuts the staircase's corners
    // and smoothing shrinks a little: on a ball only ~4 voxels across (2×2×3 mm) that costs
    // ~17 %, never a gain.
    let tumour = models.iter().find(|m| m.role == Role::Tumor).unwrap();
    let voxels = phantom.truth.voxelised_mm3(Role::Tumor);
    let rel = (tumour.mesh.signed_volume() - voxels) / voxels;
    assert!(
        rel < 0.0 && rel > -0.2,
        "tumour {} vs voxels {voxels}",
        tumour.mesh.signed_volume()
    );
}

#[test]
fn mcsd_parenchyma_of_the_small_phantom_is_labelled_and_volume_true() {
    let phantom = generate(&PhantomSpec::small()).unwrap();
    let roles = RoleMap::default();
    let options = ModelOptions {
        parenchyma: ParenchymaMethod::Mcsd,
        ..ModelOptions::default()
    };
    let models = patient_models(&phantom.labels, &roles, &options, &mut |_| true)
        .unwrap()
        .models;
    let liver = &models[0];
    assert_eq!(liver.role, Role::Parenchyma);
    assert_eq!(liver.method, "mcsd");
    assert!(models.iter().all(|m| m.method == "mcsd"));
    assert!(liver.mesh.report().watertight);
    // The whole liver envelope by marching cubes + smoothing: on a ball 60 voxels across MCSD
    // is within 3 % of the analytic volume (above); the liver is larger still.
    let truth = phantom.truth.liver.volume_mm3;
    let rel = (liver.mesh.signed_volume() - truth) / truth;
    assert!(rel.abs() < 0.03, "MCSD liver off by {rel}");
}

#[test]
fn quick_study_scores_every_model() {
    let m = ball();
    let mut n = 0;
    let config = StudyConfig::quick();
    let result = run(&m, &config, &mut |_| n += 1).unwrap();
    assert_eq!(n, config.len());
    assert_eq!(result.study.models.len(), config.len());
    assert!(result.study.p_best.is_some() && result.study.c_best.is_some());
    assert!(result.study.c_sim.is_some());
    assert!(!result.study.pareto_front.is_empty());
    // More smoothing, lower curvature spread; decimation, fewer polygons.
    let polys = |label: &str| {
        result
            .study
            .models
            .iter()
            .find(|s| s.record.label == label)
            .unwrap()
            .record
            .polys
    };
    assert!(polys("MCSD s=0 e=0.5") < polys("MCSD s=0 e=0.0"));
    assert!(result.volumes_ml.iter().all(|&v| v > 100.0 && v < 125.0));
}
