//! A left-atrium phantom for the electro-anatomical mapping study (thesis ch. 9): an
//! ellipsoid body with pulmonary-vein tubes (capsules) that start inside it and leave through
//! its posterior roof. Its truth: area-uniform surface samples with exact outward normals, the
//! exact ostia (where each tube meets the body) and a voxelisation with the LASC'13 labels.

use std::f64::consts::PI;

use rand::Rng;
use rayon::prelude::*;
use resecta_geom::{LabelMap, Real, Vec3, Volume};
use serde::{Deserialize, Serialize};

use crate::error::PhantomError;
use crate::implicit::Solid;
use crate::spec::{EllipsoidSpec, GridSpec, Orientation, build_grid, finite, positive};

/// LASC'13 label of the atrial body.
pub const BODY_LABEL: u16 = 36;
/// LASC'13 labels of the four pulmonary veins, in [`AtriumSpec::veins`] order.
pub const VEIN_LABELS: [u16; 4] = [76, 77, 78, 79];

/// One pulmonary vein: the tube of `radius` around the segment `from` (inside the body) →
/// `to` (outside, the clipped end, capped by a half ball).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VeinSpec {
    pub from: [Real; 3],
    pub to: [Real; 3],
    pub radius: Real,
}

/// An atrium: body ellipsoid and up to four veins (RAS mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AtriumSpec {
    pub body: EllipsoidSpec,
    pub veins: Vec<VeinSpec>,
}

impl AtriumSpec {
    /// An adult-sized atrium centred at the origin: body 48 × 36 × 40 mm, four veins of
    /// 11–14 mm diameter leaving the posterior roof laterally (left veins at +x, right at −x,
    /// posterior is −y, superior +z), about 18 mm of each outside the body.
    pub fn standard() -> Self {
        let vein = |from: [Real; 3], to: [Real; 3], radius| VeinSpec { from, to, radius };
        Self {
            body: EllipsoidSpec {
                center: [0.0; 3],
                radii: [24.0, 18.0, 20.0],
                rotation: Orientation::default(),
            },
            veins: vec![
                vein([6.0, -3.0, 4.0], [34.0, -16.0, 24.0], 6.0),
                vein([6.0, -3.0, -1.0], [36.0, -18.0, -4.0], 5.5),
                vein([-6.0, -3.0, 4.0], [-32.0, -18.0, 25.0], 7.0),
                vein([-6.0, -3.0, -1.0], [-34.0, -19.0, -5.0], 6.0),
            ],
        }
    }
}

/// Area-uniform samples of a surface with unit outward normals.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SurfaceSamples {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// 0 for the body, `1 + v` for vein `v`.
    pub part: Vec<u8>,
    /// The surface area each sample stands for, mm² (the same for all).
    pub area_per_sample: Real,
}

/// The checked solids of an [`AtriumSpec`].
#[derive(Debug, Clone, PartialEq)]
pub struct Atrium {
    body: Solid,
    radii: [Real; 3],
    veins: Vec<Solid>,
}

/// Points of the body's surface per unit sphere direction for its area integral.
const AREA_QUADRATURE: usize = 200_000;

impl Atrium {
    /// Checks `spec`: finite, positive sizes, an orthonormal rotation, one to four veins each
    /// starting inside the body and ending outside it.
    pub fn new(spec: &AtriumSpec) -> Result<Self, PhantomError> {
        let b = &spec.body;
        finite("body centre", &b.center)?;
        for r in b.radii {
            positive("body radius", r)?;
        }
        let body = Solid::Ellipsoid {
            center: b.center.into(),
            axes: b.rotation.matrix("body rotation")?,
            radii: b.radii,
        };
        if spec.veins.is_empty() || spec.veins.len() > VEIN_LABELS.len() {
            return Err(PhantomError::VeinCount {
                got: spec.veins.len(),
            });
        }
        let mut veins = Vec::with_capacity(spec.veins.len());
        for (i, v) in spec.veins.iter().enumerate() {
            let name = format!("vein[{i}]");
            finite(&name, &v.from)?;
            finite(&name, &v.to)?;
            positive(&format!("{name} radius"), v.radius)?;
            let (a, z) = (Vec3::from(v.from), Vec3::from(v.to));
            if body.signed_distance(a) > -v.radius || body.signed_distance(z) < v.radius {
                return Err(PhantomError::VeinPlacement { index: i });
            }
            veins.push(Solid::Capsule {
                a,
                b: z,
                radius: v.radius,
            });
        }
        Ok(Self {
            body,
            radii: b.radii,
            veins,
        })
    }

    /// The body ellipsoid.
    pub fn body(&self) -> &Solid {
        &self.body
    }

    /// The vein capsules.
    pub fn veins(&self) -> &[Solid] {
        &self.veins
    }

    /// Whether `p` lies in the atrium (body or a vein).
    pub fn contains(&self, p: Vec3) -> bool {
        self.body.contains(p) || self.veins.iter().any(|v| v.contains(p))
    }

    /// Whether a point on part `part`'s surface lies on the union's surface (not strictly
    /// inside another part).
    fn exposed(&self, part: usize, p: Vec3) -> bool {
        let solids = std::iter::once(&self.body).chain(&self.veins);
        solids
            .enumerate()
            .all(|(i, s)| i == part || s.signed_distance(p) >= -1e-9)
    }

    /// Area-uniform samples of the atrium's surface with exact normals: `count` proposals
    /// spread over the parts by their areas, each uniform by area on its part; those inside
    /// another part are dropped (about a quarter for [`AtriumSpec::standard`]). Every kept
    /// sample stands for the same area.
    pub fn surface_samples(&self, count: usize, rng: &mut impl Rng) -> SurfaceSamples {
        let body_area = ellipsoid_area(self.radii);
        let areas: Vec<Real> = std::iter::once(body_area)
            .chain(self.veins.iter().map(capsule_area))
            .collect();
        let total: Real = areas.iter().sum();
        let per = total / count.max(1) as Real;
        let mut out = SurfaceSamples {
            area_per_sample: per,
            ..SurfaceSamples::default()
        };
        for (part, area) in areas.iter().enumerate() {
            let proposals = (area / per).round() as usize;
            for _ in 0..proposals {
                let p = if part == 0 {
                    self.ellipsoid_point(rng)
                } else {
                    capsule_point(&self.veins[part - 1], rng)
                };
                if self.exposed(part, p) {
                    let solid = if part == 0 {
                        &self.body
                    } else {
                        &self.veins[part - 1]
                    };
                    out.positions.push(p);
                    out.normals.push(solid.normal(p));
                    out.part.push(part as u8);
                }
            }
        }
        out
    }

    /// A point uniform by area on the body: a uniform direction mapped onto the ellipsoid,
    /// kept with probability proportional to the area element there.
    fn ellipsoid_point(&self, rng: &mut impl Rng) -> Vec3 {
        let Solid::Ellipsoid {
            center,
            axes,
            radii,
        } = &self.body
        else {
            return Vec3::zeros();
        };
        let rmin = radii.iter().copied().fold(Real::INFINITY, Real::min);
        loop {
            let u = unit_direction(rng);
            let stretch = Vec3::new(u.x / radii[0], u.y / radii[1], u.z / radii[2]).norm();
            if rng.random::<Real>() < rmin * stretch {
                let local = Vec3::new(u.x * radii[0], u.y * radii[1], u.z * radii[2]);
                return center + axes * local;
            }
        }
    }

    /// `per_vein` points of each vein's ostium, the curve where its tube meets the body
    /// (exact to 1e-9 mm along each generator line of the tube).
    pub fn ostia(&self, per_vein: usize) -> Vec<Vec<Vec3>> {
        self.veins
            .iter()
            .map(|v| {
                let Solid::Capsule { a, b, radius } = v else {
                    return Vec::new();
                };
                let axis = (b - a).normalize();
                let e1 = axis.cross(&any_perpendicular(axis)).normalize();
                let e2 = axis.cross(&e1);
                (0..per_vein)
                    .map(|k| {
                        let t = 2.0 * PI * k as Real / per_vein as Real;
                        let off = (e1 * t.cos() + e2 * t.sin()) * *radius;
                        // Along the generator line a + off + s·axis, the body is left once.
                        let len = (b - a).norm();
                        let (mut lo, mut hi) = (0.0, len);
                        for _ in 0..80 {
                            let mid = 0.5 * (lo + hi);
                            if self.body.contains(a + off + axis * mid) {
                                lo = mid;
                            } else {
                                hi = mid;
                            }
                        }
                        a + off + axis * (0.5 * (lo + hi))
                    })
                    .collect()
            })
            .collect()
    }

    /// A label map on `grid`: [`BODY_LABEL`] inside the body, [`VEIN_LABELS`] in the veins
    /// outside it (a voxel takes the label of the part holding its centre).
    pub fn label_map(&self, grid: &GridSpec) -> Result<LabelMap, PhantomError> {
        let grid = build_grid(grid, None)?;
        let [nx, ny, _] = grid.dims();
        let mut labels = Volume::filled(grid.clone(), 0u16);
        labels
            .data_mut()
            .par_chunks_mut(nx * ny)
            .enumerate()
            .for_each(|(k, slab)| {
                for (idx, v) in slab.iter_mut().enumerate() {
                    let p = grid.voxel_center([idx % nx, idx / nx, k]);
                    *v = if self.body.contains(p) {
                        BODY_LABEL
                    } else {
                        self.veins
                            .iter()
                            .position(|s| s.contains(p))
                            .map_or(0, |i| VEIN_LABELS[i])
                    };
                }
            });
        Ok(labels)
    }
}

/// A uniformly distributed unit vector.
fn unit_direction(rng: &mut impl Rng) -> Vec3 {
    let z: Real = rng.random_range(-1.0..=1.0);
    let phi: Real = rng.random_range(0.0..2.0 * PI);
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

fn any_perpendicular(v: Vec3) -> Vec3 {
    if v.x.abs() < 0.9 {
        Vec3::x()
    } else {
        Vec3::y()
    }
}

/// Surface area of a capsule (cylinder and two half balls).
fn capsule_area(s: &Solid) -> Real {
    match s {
        Solid::Capsule { a, b, radius } => {
            2.0 * PI * radius * (b - a).norm() + 4.0 * PI * radius * radius
        }
        Solid::Ellipsoid { .. } | Solid::Ball { .. } => 0.0,
    }
}

/// A point uniform by area on a capsule's surface.
fn capsule_point(s: &Solid, rng: &mut impl Rng) -> Vec3 {
    let Solid::Capsule { a, b, radius } = s else {
        return Vec3::zeros();
    };
    let len = (b - a).norm();
    let axis = (b - a) / len;
    let cylinder = 2.0 * PI * radius * len;
    let caps = 4.0 * PI * radius * radius;
    if rng.random::<Real>() * (cylinder + caps) < cylinder {
        let e1 = axis.cross(&any_perpendicular(axis)).normalize();
        let e2 = axis.cross(&e1);
        let t: Real = rng.random_range(0.0..2.0 * PI);
        let h: Real = rng.random_range(0.0..=len);
        a + axis * h + (e1 * t.cos() + e2 * t.sin()) * *radius
    } else {
        // A point of the whole ball's sphere, moved to the cap on its side.
        let u = unit_direction(rng);
        let end = if u.dot(&axis) >= 0.0 { b } else { a };
        end + u * *radius
    }
}

/// `n` nearly uniform unit directions: the Fibonacci lattice (equal-area bands in z, golden-angle
/// steps in longitude).
pub fn fibonacci_sphere(n: usize) -> Vec<Vec3> {
    let golden = PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as Real + 1.0) / n as Real;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as Real;
            Vec3::new(r * t.cos(), r * t.sin(), z)
        })
        .collect()
}

/// Surface area of an ellipsoid: `4π·r₀r₁r₂·E[|D⁻¹u|]` over uniform directions `u`, by a
/// Fibonacci-lattice quadrature (relative error < 1e-6 for the aspect ratios used here).
pub fn ellipsoid_area(radii: [Real; 3]) -> Real {
    let dirs = fibonacci_sphere(AREA_QUADRATURE);
    let sum: Real = dirs
        .iter()
        .map(|u| Vec3::new(u.x / radii[0], u.y / radii[1], u.z / radii[2]).norm())
        .sum();
    4.0 * PI * radii[0] * radii[1] * radii[2] * sum / dirs.len() as Real
}
