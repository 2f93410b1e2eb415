//! The ellipsoid-liver phantom the planner tests share: a 60×45×40 mm ellipsoid with a 10 mm
//! spherical tumour on an oblique anisotropic grid.
#![allow(dead_code, clippy::unwrap_used)]

use std::sync::{Arc, OnceLock};

use resecta_geom::{Real, RoleMap};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate};
use resecta_plan::Anatomy;

pub const RADII: [Real; 3] = [60.0, 45.0, 40.0];
pub const TUMOUR: [Real; 3] = [25.0, 0.0, 0.0];
pub const TUMOUR_R: Real = 10.0;

pub fn spec() -> PhantomSpec {
    PhantomSpec {
        grid: GridSpec::centred(
            [132, 100, 66],
            [1.0, 1.0, 1.3],
            [0.0, 0.0, 0.0],
            Orientation::EulerDeg([4.0, -3.0, 7.0]),
        ),
        liver: vec![EllipsoidSpec {
            center: [0.0, 0.0, 0.0],
            radii: RADII,
            rotation: Orientation::default(),
        }],
        tumors: vec![SphereSpec {
            center: TUMOUR,
            radius: TUMOUR_R,
        }],
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.05,
    }
}

pub fn anatomy() -> Arc<Anatomy> {
    static A: OnceLock<Arc<Anatomy>> = OnceLock::new();
    A.get_or_init(|| {
        let p = generate(&spec()).unwrap();
        Arc::new(Anatomy::new(&p.labels, &spec().roles).unwrap())
    })
    .clone()
}
