//! The phantom, resection and drag the planning benches share.
#![allow(dead_code)] // each bench uses a part

use resecta_geom::{Real, RoleMap};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec};
use resecta_plan::{PlanEvent, Resection};

/// The liver of [`spec`] with a tumour of radius `r` at (35, 10, 5).
pub fn spec_with_tumour(dims: [usize; 3], spacing: [Real; 3], r: Real) -> PhantomSpec {
    PhantomSpec {
        grid: GridSpec::centred(dims, spacing, [0.0; 3], Orientation::default()),
        liver: vec![
            EllipsoidSpec {
                center: [0.0, 0.0, 0.0],
                radii: [95.0, 75.0, 65.0],
                rotation: Orientation::EulerDeg([0.0, 0.0, 15.0]),
            },
            EllipsoidSpec {
                center: [-60.0, 20.0, 10.0],
                radii: [60.0, 50.0, 45.0],
                rotation: Orientation::default(),
            },
        ],
        tumors: vec![SphereSpec {
            center: [35.0, 10.0, 5.0],
            radius: r,
        }],
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.5,
    }
}

pub fn planar(res: usize) -> Resection {
    let pts = (0..16)
        .map(|k| {
            let (i, j) = ((k / 4) as Real / 3.0, (k % 4) as Real / 3.0);
            [5.0, -120.0 + 240.0 * i, -110.0 + 220.0 * j]
        })
        .collect();
    let mut r = Resection::new("r1", [4, 4], pts);
    r.resolution = [res, res];
    r
}

pub fn edit(k: u64) -> PlanEvent {
    // Drag an inner control point back and forth, as a surgeon does.
    let dx = if k.is_multiple_of(2) { 8.0 } else { 5.0 };
    PlanEvent::SetControlPoint {
        name: "r1".into(),
        i: 1,
        j: 2,
        point: [dx, -40.0, 36.7],
    }
}
