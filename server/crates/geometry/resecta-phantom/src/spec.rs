//! The serde description of a phantom, its validation, and ready-made specs.

use nalgebra::Rotation3;
use resecta_geom::{GeomError, Grid, Mat3, Real, Role, RoleMap, Vec3, VoxelLimit};
use serde::{Deserialize, Serialize};

use crate::error::PhantomError;
use crate::implicit::Solid;

/// A rotation (or, for grids, any orthonormal direction matrix).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Orientation {
    #[default]
    Identity,
    /// `[roll, pitch, yaw]` in degrees: `R = Rz(yaw)·Ry(pitch)·Rx(roll)`.
    EulerDeg([Real; 3]),
    /// Rows of an orthonormal matrix whose columns are the rotated x, y, z axes.
    Matrix([[Real; 3]; 3]),
}

impl Orientation {
    /// The matrix, checked to be finite and orthonormal (to 1e-6).
    pub fn matrix(&self, what: &str) -> Result<Mat3, PhantomError> {
        let m = match self {
            Orientation::Identity => Mat3::identity(),
            Orientation::EulerDeg(a) => {
                finite(what, a)?;
                let [r, p, y] = a.map(Real::to_radians);
                Rotation3::from_euler_angles(r, p, y).into_inner()
            }
            Orientation::Matrix(rows) => {
                finite(what, rows.as_flattened())?;
                Mat3::from_row_slice(rows.as_flattened())
            }
        };
        if (m.transpose() * m - Mat3::identity()).abs().max() > 1e-6 {
            return Err(PhantomError::NotOrthonormal { what: what.into() });
        }
        Ok(m)
    }
}

/// The voxel grid: `world = origin + direction·diag(spacing)·ijk` (RAS mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridSpec {
    pub dims: [usize; 3],
    pub spacing: [Real; 3],
    pub origin: [Real; 3],
    #[serde(default)]
    pub direction: Orientation,
}

impl GridSpec {
    /// A grid whose central voxel position (continuous index `(dims − 1)/2`) is `centre`.
    pub fn centred(
        dims: [usize; 3],
        spacing: [Real; 3],
        centre: [Real; 3],
        direction: Orientation,
    ) -> Self {
        // An invalid direction is refused later by `generate`; the origin is then moot.
        let r = direction
            .matrix("grid direction")
            .unwrap_or_else(|_| Mat3::identity());
        let half = Vec3::from_fn(|i, _| spacing[i] * (dims[i].max(1) - 1) as Real / 2.0);
        let origin = Vec3::from(centre) - r * half;
        Self {
            dims,
            spacing,
            origin: origin.into(),
            direction,
        }
    }
}

/// An ellipsoid `{centre + R·diag(radii)·u : |u| ≤ 1}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EllipsoidSpec {
    pub center: [Real; 3],
    pub radii: [Real; 3],
    #[serde(default)]
    pub rotation: Orientation,
}

/// A spherical tumour.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SphereSpec {
    pub center: [Real; 3],
    pub radius: Real,
}

/// A tube of constant radius around a polyline (a union of capsules, one per segment).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VesselSpec {
    /// `portal`, `hepatic` or `vessel`.
    pub role: Role,
    pub radius: Real,
    pub points: Vec<[Real; 3]>,
}

fn default_tolerance() -> Real {
    0.05
}

/// A synthetic liver: a union of ellipsoids, spherical tumours inside it, tube vessels.
///
/// Labels: a voxel takes the label of the highest-priority shape that contains its centre
/// (closed shapes): tumour > portal > hepatic > vessel > parenchyma (liver ellipsoids) >
/// background 0. The label of a role is the first label listed for it in `roles`. Vessels are
/// not clipped to the liver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhantomSpec {
    pub grid: GridSpec,
    /// The liver: union of these ellipsoids (at least one).
    pub liver: Vec<EllipsoidSpec>,
    /// Each must lie inside one liver ellipsoid.
    #[serde(default)]
    pub tumors: Vec<SphereSpec>,
    #[serde(default)]
    pub vessels: Vec<VesselSpec>,
    #[serde(default)]
    pub roles: RoleMap,
    /// Largest grid accepted (voxels); `None`: the [`VoxelLimit`] default.
    #[serde(default)]
    pub max_voxels: Option<u64>,
    /// Target accuracy of numerically integrated volumes, as a thickness in mm: the error bound
    /// is about this times the surface area involved (see [`crate::volume`]).
    #[serde(default = "default_tolerance")]
    pub truth_tolerance_mm: Real,
}

/// A named solid of the validated spec, with the role its voxels get.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Part {
    pub name: String,
    pub role: Role,
    pub solid: Solid,
}

/// A validated spec: the grid and every solid (vessels split into capsules).
#[derive(Debug, Clone)]
pub(crate) struct Scene {
    pub grid: Grid,
    pub parts: Vec<Part>,
    /// Label value of every role in use.
    pub labels: Vec<(Role, u16)>,
}

pub(crate) const PRIORITY: [Role; 5] = [
    Role::Tumor,
    Role::Portal,
    Role::Hepatic,
    Role::Vessel,
    Role::Parenchyma,
];

pub(crate) fn finite(what: &str, v: &[Real]) -> Result<(), PhantomError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(PhantomError::NonFinite { what: what.into() })
    }
}

pub(crate) fn positive(what: &str, v: Real) -> Result<(), PhantomError> {
    finite(what, &[v])?;
    if v > 0.0 {
        Ok(())
    } else {
        Err(PhantomError::NonPositive {
            what: what.into(),
            value: v,
        })
    }
}

/// The grid of `g`, checked, with at most `max_voxels` voxels (`None`: the [`VoxelLimit`]
/// default).
pub(crate) fn build_grid(g: &GridSpec, max_voxels: Option<u64>) -> Result<Grid, PhantomError> {
    finite("grid spacing", &g.spacing)?;
    finite("grid origin", &g.origin)?;
    let dir = g.direction.matrix("grid direction")?;
    let limit = max_voxels.map_or_else(VoxelLimit::default, VoxelLimit);
    Grid::with_limit(g.dims, g.spacing, Vec3::from(g.origin), dir, limit).map_err(|e| match e {
        GeomError::TooManyVoxels { dims, limit } => PhantomError::VoxelLimit { dims, limit },
        e @ (GeomError::EmptyDims(_)
        | GeomError::BadSpacing(_)
        | GeomError::BadOrigin(_)
        | GeomError::SingularDirection
        | GeomError::DataLength { .. }
        | GeomError::VertexIndexOutOfRange { .. }
        | GeomError::TooManyVertices
        | GeomError::NonFiniteVertex(_)
        | GeomError::AttributeLength { .. }
        | GeomError::LabelInTwoRoles { .. }
        | GeomError::BackgroundLabel
        | GeomError::EmptyRole(_)
        | GeomError::NonOrthogonalGrid
        | GeomError::TooFewPoints { .. }
        | GeomError::InvalidParameter { .. }
        | GeomError::TooManyTriangles { .. }
        | GeomError::NotClosed { .. }
        | GeomError::EmptyMesh) => PhantomError::Geom(e),
    })
}

impl PhantomSpec {
    /// Checks everything and builds the solids; nothing is allocated per voxel here.
    pub(crate) fn scene(&self) -> Result<Scene, PhantomError> {
        let grid = build_grid(&self.grid, self.max_voxels)?;
        positive("truth_tolerance_mm", self.truth_tolerance_mm)?;
        if self.liver.is_empty() {
            return Err(PhantomError::NoLiver);
        }
        let mut parts = Vec::new();
        for (n, e) in self.liver.iter().enumerate() {
            let name = format!("liver[{n}]");
            finite(&name, &e.center)?;
            for r in e.radii {
                positive(&format!("{name} radius"), r)?;
            }
            let axes = e.rotation.matrix(&format!("{name} rotation"))?;
            parts.push(Part {
                name,
                role: Role::Parenchyma,
                solid: Solid::Ellipsoid {
                    center: e.center.into(),
                    axes,
                    radii: e.radii,
                },
            });
        }
        let livers: Vec<Solid> = parts.iter().map(|p| p.solid.clone()).collect();
        for (n, t) in self.tumors.iter().enumerate() {
            let name = format!("tumor[{n}]");
            finite(&name, &t.center)?;
            positive(&format!("{name} radius"), t.radius)?;
            let c = Vec3::from(t.center);
            // Inside an ellipsoid iff the centre is inside at depth ≥ radius.
            if !livers.iter().any(|l| l.signed_distance(c) <= -t.radius) {
                return Err(PhantomError::TumorOutsideLiver { index: n });
            }
            parts.push(Part {
                name,
                role: Role::Tumor,
                solid: Solid::Ball {
                    center: c,
                    radius: t.radius,
                },
            });
        }
        for (n, v) in self.vessels.iter().enumerate() {
            let name = format!("vessel[{n}]");
            if !matches!(v.role, Role::Portal | Role::Hepatic | Role::Vessel) {
                return Err(PhantomError::NotAVesselRole {
                    index: n,
                    role: v.role,
                });
            }
            positive(&format!("{name} radius"), v.radius)?;
            if v.points.len() < 2 {
                return Err(PhantomError::TooFewPoints {
                    index: n,
                    got: v.points.len(),
                });
            }
            finite(&name, v.points.as_flattened())?;
            for (s, w) in v.points.windows(2).enumerate() {
                parts.push(Part {
                    name: format!("{name}.segment[{s}]"),
                    role: v.role,
                    solid: Solid::Capsule {
                        a: w[0].into(),
                        b: w[1].into(),
                        radius: v.radius,
                    },
                });
            }
        }
        // Every solid lies within the grid's voxel cuboids: continuous index in [−½, n − ½].
        let inv = grid
            .linear()
            .try_inverse()
            .ok_or(PhantomError::Geom(GeomError::SingularDirection))?;
        let o = inv * grid.origin();
        for p in &parts {
            let (lo, hi) = p.solid.extent_under(&inv);
            let inside = (0..3)
                .all(|i| lo[i] - o[i] >= -0.5 && hi[i] - o[i] <= grid.dims()[i] as Real - 0.5);
            if !inside {
                return Err(PhantomError::OutsideGrid {
                    what: p.name.clone(),
                });
            }
        }
        let mut labels = Vec::new();
        for role in PRIORITY {
            if parts.iter().any(|p| p.role == role) {
                let l = *self
                    .roles
                    .labels(role)
                    .first()
                    .ok_or(PhantomError::MissingRole(role))?;
                labels.push((role, l));
            }
        }
        Ok(Scene {
            grid,
            parts,
            labels,
        })
    }

    /// A liver-sized phantom (~1.5 l union of two ellipsoids, tumours of 15 and 25 mm, one portal
    /// and one hepatic tube) on an oblique 0.8×0.8×2.5 mm grid of 300×230×64 voxels. Generates
    /// in about 0.45 s in release on 2 cores (labels ~20 ms; the rest is the numeric truth, liver
    /// volume ±0.025 %).
    pub fn demo() -> Self {
        let rot = |r, p, y| Orientation::EulerDeg([r, p, y]);
        Self {
            grid: GridSpec::centred(
                [300, 230, 64],
                [0.8, 0.8, 2.5],
                [-10.0, 5.0, 0.0],
                rot(2.0, -3.0, 4.0),
            ),
            liver: vec![
                EllipsoidSpec {
                    center: [25.0, 5.0, 0.0],
                    radii: [80.0, 70.0, 55.0],
                    rotation: rot(0.0, 5.0, 10.0),
                },
                EllipsoidSpec {
                    center: [-55.0, 10.0, 10.0],
                    radii: [55.0, 40.0, 30.0],
                    rotation: rot(5.0, 0.0, -15.0),
                },
            ],
            tumors: vec![
                SphereSpec {
                    center: [40.0, -10.0, 5.0],
                    radius: 25.0,
                },
                SphereSpec {
                    center: [-55.0, 15.0, 10.0],
                    radius: 15.0,
                },
            ],
            vessels: vec![
                VesselSpec {
                    role: Role::Portal,
                    radius: 6.0,
                    points: vec![[0.0, 30.0, -20.0], [30.0, 35.0, -15.0], [70.0, 30.0, -5.0]],
                },
                VesselSpec {
                    role: Role::Hepatic,
                    radius: 5.0,
                    points: vec![[10.0, -45.0, 25.0], [60.0, -30.0, 30.0]],
                },
            ],
            roles: RoleMap::default(),
            max_voxels: None,
            truth_tolerance_mm: default_tolerance(),
        }
    }

    /// Centre of the core ball of [`PhantomSpec::large_tumour`]'s bumpy tumour (RAS mm).
    pub const LARGE_TUMOUR_CENTRE: [Real; 3] = [30.0, -5.0, 0.0];

    /// A CT-like phantom with a large, bumpy tumour: a liver of two ellipsoids on a 512×512×130
    /// grid of 0.57×0.57×1.6 mm (slightly oblique), one portal tube, and one tumour made of a
    /// 32 mm core ball at [`Self::LARGE_TUMOUR_CENTRE`] with 26 overlapping balls of 7–13 mm on
    /// its surface (Fibonacci directions): one connected, irregular tumour of about 170 ml
    /// (333 k voxels) whose voxel-boundary margin surface has about 32 000 triangles. Its truth is
    /// the union's volume, integrated numerically with its bound (the balls overlap).
    pub fn large_tumour() -> Self {
        let rot = |r, p, y| Orientation::EulerDeg([r, p, y]);
        let c = Self::LARGE_TUMOUR_CENTRE;
        let core = 32.0;
        let mut tumors = vec![SphereSpec {
            center: c,
            radius: core,
        }];
        let n = 26;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        for k in 0..n {
            // Fibonacci sphere directions; bump centres 0.8–0.95 core radii out, radii 7–13 mm.
            let z = 1.0 - 2.0 * (k as Real + 0.5) / n as Real;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * k as Real;
            let dir = [r * phi.cos(), r * phi.sin(), z];
            let out = core * (0.8 + 0.15 * ((k * 7 % 5) as Real / 4.0));
            tumors.push(SphereSpec {
                center: std::array::from_fn(|i| c[i] + out * dir[i]),
                radius: 7.0 + 6.0 * ((k * 3 % 7) as Real / 6.0),
            });
        }
        Self {
            grid: GridSpec::centred(
                [512, 512, 130],
                [0.57, 0.57, 1.6],
                [-5.0, 5.0, 0.0],
                rot(1.0, -1.5, 2.0),
            ),
            liver: vec![
                EllipsoidSpec {
                    center: [20.0, 5.0, 0.0],
                    radii: [95.0, 85.0, 75.0],
                    rotation: rot(0.0, 5.0, 10.0),
                },
                EllipsoidSpec {
                    center: [-70.0, 10.0, 10.0],
                    radii: [55.0, 45.0, 35.0],
                    rotation: rot(5.0, 0.0, -15.0),
                },
            ],
            tumors,
            vessels: vec![VesselSpec {
                role: Role::Portal,
                radius: 6.0,
                points: vec![
                    [-40.0, 40.0, -30.0],
                    [0.0, 50.0, -25.0],
                    [60.0, 45.0, -20.0],
                ],
            }],
            roles: RoleMap::default(),
            max_voxels: None,
            truth_tolerance_mm: default_tolerance(),
        }
    }

    /// A coarse, fast phantom for tests: one ellipsoid, one tumour, one portal capsule on an
    /// oblique 2×2×3 mm grid.
    pub fn small() -> Self {
        Self {
            grid: GridSpec::centred(
                [48, 40, 26],
                [2.0, 2.0, 3.0],
                [1.0, -2.0, 3.0],
                Orientation::EulerDeg([3.0, -2.0, 6.0]),
            ),
            liver: vec![EllipsoidSpec {
                center: [0.0, 0.0, 0.0],
                radii: [40.0, 30.0, 25.0],
                rotation: Orientation::EulerDeg([0.0, 0.0, 20.0]),
            }],
            tumors: vec![SphereSpec {
                center: [10.0, 5.0, 0.0],
                radius: 8.0,
            }],
            vessels: vec![VesselSpec {
                role: Role::Portal,
                radius: 3.0,
                points: vec![[-20.0, -5.0, -5.0], [0.0, -10.0, 0.0]],
            }],
            roles: RoleMap::default(),
            max_voxels: None,
            truth_tolerance_mm: 0.05,
        }
    }
}
