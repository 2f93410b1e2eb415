//! Voxelisation of a phantom and its truth.

use std::collections::BTreeMap;

use rayon::prelude::*;
use resecta_geom::grid::LabelMap;
use resecta_geom::{Real, Role, Vec3, Volume};
use serde::{Deserialize, Serialize};

use crate::error::PhantomError;
use crate::implicit::{Solid, segment_distance};
use crate::spec::{PRIORITY, Part, PhantomSpec, Scene};
use crate::volume::{Measure, REGIONS, integrate};

/// A generated phantom: its label map and what is exactly known about it.
#[derive(Debug, Clone, PartialEq)]
pub struct Phantom {
    pub labels: LabelMap,
    pub truth: Truth,
}

/// The analytic truth of a phantom (serialisable as JSON).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    pub spec: PhantomSpec,
    pub voxel_volume_mm3: Real,
    pub shapes: Vec<ShapeTruth>,
    /// Volume of the union of the liver ellipsoids.
    pub liver: Measure,
    /// Volume of the region labelled with each role in use (after priorities): closed form where
    /// the shapes do not interact (see [`generate`]), else numeric with a rigorous bound.
    pub roles: BTreeMap<Role, Measure>,
    /// Voxel counts and voxelised volumes of every label present (background excluded).
    pub labels: BTreeMap<u16, LabelTruth>,
    /// Leaf cells of the numeric integration.
    pub integration_leaves: u64,
}

impl Truth {
    /// Voxelised volume (mm³) of every label with `role`.
    pub fn voxelised_mm3(&self, role: Role) -> Real {
        self.labels
            .values()
            .filter(|l| l.role == role)
            .map(|l| l.volume_mm3)
            .sum()
    }
}

/// One shape of the spec with its exact measures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ShapeTruth {
    Ellipsoid {
        name: String,
        center: [Real; 3],
        radii: [Real; 3],
        /// Rows of the rotation whose columns are the ellipsoid's axes.
        rotation: [[Real; 3]; 3],
        volume_mm3: Real,
    },
    Sphere {
        name: String,
        center: [Real; 3],
        radius: Real,
        volume_mm3: Real,
    },
    Tube {
        name: String,
        role: Role,
        radius: Real,
        points: Vec<[Real; 3]>,
        length_mm: Real,
        /// Closed form for a single segment (a capsule), `None` for a bent tube.
        volume_mm3: Option<Real>,
    },
}

/// Voxels of one label.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LabelTruth {
    pub role: Role,
    pub voxels: u64,
    pub volume_mm3: Real,
}

/// Voxelises `spec` and computes its truth.
///
/// A voxel gets the label of the highest-priority shape containing its centre (closed shapes;
/// tumour > portal > hepatic > vessel > parenchyma), else 0. Closed-form role volumes are used
/// when the liver is one ellipsoid (liver), tumours are pairwise disjoint (tumour), a vessel role
/// is one capsule disjoint from tumours and higher-priority vessels (that role), and for
/// parenchyma when all of these hold and every capsule lies inside the liver; everything else
/// comes from [`crate::volume`] with its error bound.
pub fn generate(spec: &PhantomSpec) -> Result<Phantom, PhantomError> {
    let scene = spec.scene()?;
    let labels = voxelise(&scene)?;
    let (numeric, leaves) = integrate(&scene.parts, spec.truth_tolerance_mm);
    let closed = closed_forms(&scene);
    let pick = |r: usize| closed[r].map_or(numeric[r], Measure::analytic);
    let roles = scene
        .labels
        .iter()
        .map(|&(role, _)| {
            let i = PRIORITY.iter().position(|&p| p == role).unwrap_or(0);
            (role, pick(1 + i))
        })
        .collect();
    let voxel_volume = scene.grid.voxel_volume_mm3();
    let counts = labels.value_counts();
    let labels_truth = scene
        .labels
        .iter()
        .map(|&(role, l)| {
            let voxels = counts.get(&l).copied().unwrap_or(0);
            let t = LabelTruth {
                role,
                voxels,
                volume_mm3: voxels as Real * voxel_volume,
            };
            (l, t)
        })
        .collect();
    Ok(Phantom {
        labels,
        truth: Truth {
            spec: spec.clone(),
            voxel_volume_mm3: voxel_volume,
            shapes: shapes(spec),
            liver: pick(0),
            roles,
            labels: labels_truth,
            integration_leaves: leaves,
        },
    })
}

/// Label of a world point: the first role in priority whose part contains it.
fn label_at(parts: &[(u16, &Solid)], p: Vec3) -> u16 {
    parts
        .iter()
        .find(|(_, s)| s.contains(p))
        .map_or(0, |(l, _)| *l)
}

fn voxelise(scene: &Scene) -> Result<LabelMap, PhantomError> {
    let grid = &scene.grid;
    let [nx, ny, _] = grid.dims();
    let inv = grid.linear().try_inverse().ok_or(PhantomError::Geom(
        resecta_geom::GeomError::SingularDirection,
    ))?;
    let o = inv * grid.origin();
    // Parts in label priority, each with its label and index-space bounds.
    let mut parts: Vec<(u16, &Solid, Vec3, Vec3)> = Vec::new();
    for &(role, label) in &scene.labels {
        for p in scene.parts.iter().filter(|p| p.role == role) {
            let (lo, hi) = p.solid.extent_under(&inv);
            parts.push((label, &p.solid, lo - o, hi - o));
        }
    }
    let mut labels = Volume::filled(grid.clone(), 0u16);
    labels
        .data_mut()
        .par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(k, slab)| {
            let kf = k as Real;
            let in_k: Vec<_> = parts
                .iter()
                .filter(|p| p.2.z <= kf && kf <= p.3.z)
                .collect();
            if in_k.is_empty() {
                return;
            }
            for (j, row) in slab.chunks_mut(nx).enumerate() {
                let jf = j as Real;
                let active: Vec<(u16, &Solid)> = in_k
                    .iter()
                    .filter(|p| p.2.y <= jf && jf <= p.3.y)
                    .map(|p| (p.0, p.1))
                    .collect();
                if active.is_empty() {
                    continue;
                }
                let (lo, hi) = in_k
                    .iter()
                    .filter(|p| p.2.y <= jf && jf <= p.3.y)
                    .fold((Real::INFINITY, Real::NEG_INFINITY), |(a, b), p| {
                        (a.min(p.2.x), b.max(p.3.x))
                    });
                let i0 = lo.ceil().max(0.0) as usize;
                let i1 = (hi.floor().max(-1.0) + 1.0).min(nx as Real) as usize;
                for (i, v) in row.iter_mut().enumerate().take(i1).skip(i0) {
                    *v = label_at(&active, grid.voxel_center([i, j, k]));
                }
            }
        });
    Ok(labels)
}

/// Closed-form region volumes where the shapes do not interact (see [`generate`]).
fn closed_forms(scene: &Scene) -> [Option<Real>; REGIONS] {
    let of = |role: Role| -> Vec<&Part> { scene.parts.iter().filter(|p| p.role == role).collect() };
    let livers = of(Role::Parenchyma);
    let balls: Vec<(Vec3, Real)> = of(Role::Tumor)
        .iter()
        .filter_map(|p| match p.solid {
            Solid::Ball { center, radius } => Some((center, radius)),
            Solid::Ellipsoid { .. } | Solid::Capsule { .. } => None,
        })
        .collect();
    let mut out = [None; REGIONS];
    out[0] = match livers.as_slice() {
        [l] => Some(l.solid.volume()),
        _ => None,
    };
    let disjoint_balls = balls.iter().enumerate().all(|(i, a)| {
        balls[i + 1..]
            .iter()
            .all(|b| (a.0 - b.0).norm() >= a.1 + b.1)
    });
    let tumor = disjoint_balls.then(|| of(Role::Tumor).iter().map(|p| p.solid.volume()).sum());
    let mut capsules: Vec<(Vec3, Vec3, Real)> = Vec::new();
    let mut all_closed = out[0].is_some() && tumor.is_some();
    let mut taken = tumor.unwrap_or(0.0);
    for (i, &role) in PRIORITY.iter().enumerate() {
        match role {
            Role::Tumor => out[1 + i] = tumor,
            Role::Parenchyma => {}
            Role::Portal | Role::Hepatic | Role::Vessel => {
                let parts = of(role);
                let v = match parts.as_slice() {
                    [] => Some(0.0),
                    [p] => match p.solid {
                        Solid::Capsule { a, b, radius } => {
                            let free = balls
                                .iter()
                                .all(|(c, r)| segment_distance(a, b, *c, *c) >= radius + r)
                                && capsules
                                    .iter()
                                    .all(|(p, q, r)| segment_distance(a, b, *p, *q) >= radius + r);
                            capsules.push((a, b, radius));
                            free.then(|| p.solid.volume())
                        }
                        Solid::Ellipsoid { .. } | Solid::Ball { .. } => None,
                    },
                    _ => None,
                };
                out[1 + i] = v;
                all_closed &= v.is_some();
                taken += v.unwrap_or(0.0);
            }
        }
    }
    // Distance to the outside is concave in a convex solid: a capsule is inside an ellipsoid iff
    // both end points are at depth ≥ its radius.
    let caps_inside = livers.iter().all(|l| {
        capsules
            .iter()
            .all(|(a, b, r)| l.solid.signed_distance(*a) <= -r && l.solid.signed_distance(*b) <= -r)
    });
    let par = PRIORITY
        .iter()
        .position(|&r| r == Role::Parenchyma)
        .unwrap_or(0);
    if all_closed && caps_inside {
        out[1 + par] = out[0].map(|l| l - taken);
    }
    out
}

fn shapes(spec: &PhantomSpec) -> Vec<ShapeTruth> {
    use std::f64::consts::PI;
    let mut v = Vec::new();
    for (n, e) in spec.liver.iter().enumerate() {
        let m = e.rotation.matrix("").unwrap_or_default();
        v.push(ShapeTruth::Ellipsoid {
            name: format!("liver[{n}]"),
            center: e.center,
            radii: e.radii,
            rotation: [0, 1, 2].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]]),
            volume_mm3: 4.0 / 3.0 * PI * e.radii.iter().product::<Real>(),
        });
    }
    for (n, t) in spec.tumors.iter().enumerate() {
        v.push(ShapeTruth::Sphere {
            name: format!("tumor[{n}]"),
            center: t.center,
            radius: t.radius,
            volume_mm3: 4.0 / 3.0 * PI * t.radius.powi(3),
        });
    }
    for (n, t) in spec.vessels.iter().enumerate() {
        let length: Real = t
            .points
            .windows(2)
            .map(|w| (Vec3::from(w[1]) - Vec3::from(w[0])).norm())
            .sum();
        let r = t.radius;
        v.push(ShapeTruth::Tube {
            name: format!("vessel[{n}]"),
            role: t.role,
            radius: r,
            points: t.points.clone(),
            length_mm: length,
            volume_mm3: (t.points.len() == 2)
                .then(|| PI * r * r * length + 4.0 / 3.0 * PI * r.powi(3)),
        });
    }
    v
}
