//! The patient model as Slicer shows a segmentation: one model per vessel label, one per tumour
//! component, specks left out and counted; the per-component split on request.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use resecta_geom::{LabelMap, Real, Role, RoleMap, TriMesh, Vec3};
use resecta_phantom::{
    EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, VesselSpec, generate,
};
use resecta_recon::{
    ModelOptions, ParenchymaMethod, PatientModels, ReconError, SPECK_MM3, models, patient_models,
};

const PORTAL: u16 = 3;
const TUMOUR: u16 = 2;

/// A liver on an oblique 1.5 × 1.5 × 2.5 mm grid (5.625 mm³ voxels) with two tumour balls (one
/// label) and a portal label made of three disconnected tubes, plus a one-voxel tumour speck and
/// a one-voxel portal speck (5.6 mm³, below [`SPECK_MM3`]).
fn phantom() -> LabelMap {
    let tube = |a: [Real; 3], b: [Real; 3]| VesselSpec {
        role: Role::Portal,
        radius: 2.5,
        points: vec![a, b],
    };
    let spec = PhantomSpec {
        grid: GridSpec::centred(
            [64, 52, 26],
            [1.5, 1.5, 2.5],
            [0.0; 3],
            Orientation::EulerDeg([4.0, -3.0, 8.0]),
        ),
        liver: vec![EllipsoidSpec {
            center: [0.0; 3],
            radii: [42.0, 32.0, 26.0],
            rotation: Orientation::default(),
        }],
        tumors: vec![
            SphereSpec {
                center: [18.0, 8.0, 0.0],
                radius: 7.0,
            },
            SphereSpec {
                center: [-18.0, -6.0, 2.0],
                radius: 5.0,
            },
        ],
        vessels: vec![
            tube([-30.0, 15.0, -8.0], [-5.0, 18.0, -8.0]),
            tube([0.0, -18.0, 8.0], [25.0, -16.0, 8.0]),
            tube([-5.0, 0.0, -15.0], [10.0, 0.0, -15.0]),
        ],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.05,
    };
    let mut labels = generate(&spec).unwrap().labels;
    for (p, label) in [([0.0, 10.0, 15.0], TUMOUR), ([-25.0, -10.0, 12.0], PORTAL)] {
        let ijk = labels
            .grid()
            .world_to_index(Vec3::from(p))
            .map(|c| c.round() as usize);
        let ijk = [ijk.x, ijk.y, ijk.z];
        assert_eq!(labels.get(ijk), Some(1), "speck must sit in the parenchyma");
        labels.set(ijk, label);
    }
    labels
}

/// Connected pieces of a mesh (shared vertices).
fn pieces(mesh: &TriMesh) -> usize {
    let mut parent: Vec<usize> = (0..mesh.vertices().len()).collect();
    fn root(p: &mut [usize], mut v: usize) -> usize {
        while p[v] != v {
            p[v] = p[p[v]];
            v = p[v];
        }
        v
    }
    for t in mesh.triangles() {
        for e in [t[1], t[2]] {
            let (a, b) = (
                root(&mut parent, t[0] as usize),
                root(&mut parent, e as usize),
            );
            parent[a] = b;
        }
    }
    let mut roots: Vec<usize> = (0..parent.len()).map(|v| root(&mut parent, v)).collect();
    roots.sort_unstable();
    roots.dedup();
    roots.len()
}

fn build(labels: &LabelMap, options: &ModelOptions) -> PatientModels {
    let options = ModelOptions {
        parenchyma: ParenchymaMethod::Mcsd,
        ..*options
    };
    patient_models(labels, &RoleMap::default(), &options, &mut |_| true).unwrap()
}

fn names(built: &PatientModels, role: Role) -> Vec<String> {
    built
        .models
        .iter()
        .filter(|m| m.role == role)
        .map(|m| m.name())
        .collect()
}

#[test]
fn one_model_per_vessel_label_and_per_tumour_component_specks_counted() {
    let labels = phantom();
    let built = build(&labels, &ModelOptions::default());
    assert_eq!(names(&built, Role::Parenchyma), ["parenchyma"]);
    assert_eq!(names(&built, Role::Tumor), ["tumor_1", "tumor_2"]);
    assert_eq!(names(&built, Role::Portal), ["portal_1"]);
    let portal = built
        .models
        .iter()
        .find(|m| m.role == Role::Portal)
        .unwrap();
    assert_eq!(portal.label, Some(PORTAL));
    // Three closed tubes in one mesh, the speck not among them.
    let report = portal.mesh.report();
    assert!(report.watertight, "{report:?}");
    assert_eq!(pieces(&portal.mesh), 3);
    let portal_voxels = labels.data().iter().filter(|&&l| l == PORTAL).count();
    assert_eq!(portal.voxels, portal_voxels - 1);
    // Tumours largest first, each its label's.
    let tumours: Vec<_> = built
        .models
        .iter()
        .filter(|m| m.role == Role::Tumor)
        .collect();
    assert!(tumours[0].voxels > tumours[1].voxels);
    assert!(tumours.iter().all(|m| m.label == Some(TUMOUR)));
    // The specks: one component of one voxel per role, in ml.
    let voxel_mm3 = labels.grid().voxel_volume_mm3();
    assert!(voxel_mm3 < SPECK_MM3);
    assert_eq!(built.dropped.len(), 2);
    for (d, role) in built.dropped.iter().zip([Role::Tumor, Role::Portal]) {
        assert_eq!((d.role, d.components, d.voxels), (role, 1, 1));
        assert!((d.volume_mm3 - voxel_mm3).abs() < 1e-9);
    }
}

#[test]
fn split_components_gives_one_vessel_model_per_piece() {
    let labels = phantom();
    let options = ModelOptions {
        split_components: true,
        ..ModelOptions::default()
    };
    let built = build(&labels, &options);
    assert_eq!(
        names(&built, Role::Portal),
        ["portal_1", "portal_2", "portal_3"]
    );
    assert_eq!(names(&built, Role::Tumor), ["tumor_1", "tumor_2"]);
    let portal: Vec<_> = built
        .models
        .iter()
        .filter(|m| m.role == Role::Portal)
        .collect();
    assert!(portal.windows(2).all(|w| w[0].voxels >= w[1].voxels));
    assert!(
        portal
            .iter()
            .all(|m| m.label == Some(PORTAL) && pieces(&m.mesh) == 1)
    );
    assert_eq!(built.dropped.len(), 2);
}

#[test]
fn the_speck_volume_is_per_request_for_vessels_and_fixed_for_tumours() {
    let labels = phantom();
    // Keeping everything: the vessel speck joins its label's model, the tumour speck stays out.
    let keep_all = build(
        &labels,
        &ModelOptions {
            min_component_mm3: 0.0,
            ..ModelOptions::default()
        },
    );
    let portal = keep_all
        .models
        .iter()
        .find(|m| m.role == Role::Portal)
        .unwrap();
    assert_eq!(pieces(&portal.mesh), 4);
    assert_eq!(names(&keep_all, Role::Tumor).len(), 2);
    assert_eq!(keep_all.dropped.len(), 1);
    assert_eq!(keep_all.dropped[0].role, Role::Tumor);
    // A volume above every tube: no portal model, all of it counted.
    let none = build(
        &labels,
        &ModelOptions {
            min_component_mm3: 1e6,
            ..ModelOptions::default()
        },
    );
    assert!(names(&none, Role::Portal).is_empty());
    let d = none
        .dropped
        .iter()
        .find(|d| d.role == Role::Portal)
        .unwrap();
    assert_eq!(d.components, 4);
    // The tumour list is the planner's.
    let targets = models::tumours(&labels, &RoleMap::default()).unwrap();
    assert_eq!(targets.len(), 1);
    assert_eq!(targets[0].parts.len(), 2);
    assert_eq!(targets[0].parts.dropped, 1);
}

#[test]
fn a_bad_speck_volume_is_refused() {
    let labels = phantom();
    for v in [-1.0, Real::NAN, Real::INFINITY] {
        let options = ModelOptions {
            min_component_mm3: v,
            ..ModelOptions::default()
        };
        let r = patient_models(&labels, &RoleMap::default(), &options, &mut |_| true);
        assert!(
            matches!(
                r,
                Err(ReconError::InvalidParameter {
                    name: "min_component_mm3",
                    ..
                })
            ),
            "{v}"
        );
    }
}
