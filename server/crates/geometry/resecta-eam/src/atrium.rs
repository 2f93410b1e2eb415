//! Reference atria: where catheter points are drawn from and the error is measured from.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use resecta_geom::{LabelMap, Real, TriMesh, Vec3};
use resecta_phantom::Atrium;
use resecta_poisson::OrientedPoints;
use resecta_recon::{McsdParams, mcsd, psr};

use crate::EamError;
use crate::split::Split;

/// A reference atrium for the study.
#[derive(Debug, Clone)]
pub struct StudyAtrium {
    /// What it is (`phantom`, a file stem), for reports; never a patient identifier.
    pub name: String,
    /// Dense oriented surface samples with the area each stands for: the points a catheter
    /// can touch.
    pub pool: OrientedPoints,
    /// Per pool point: in the upper part.
    pub upper: Vec<bool>,
    /// Area-uniform reference points: the error is the median distance from these to a
    /// reconstruction.
    pub reference: Vec<Vec3>,
    /// The reference surface, where there is one (label maps: MCSD; meshes: the mesh).
    pub reference_mesh: Option<TriMesh>,
    pub split: Split,
    /// Surface area of the upper and of the lower part, mm² (sums of pool areas).
    pub upper_area_mm2: Real,
    pub lower_area_mm2: Real,
}

/// How a mesh input is split.
#[derive(Debug, Clone, PartialEq)]
pub enum MeshSplit {
    /// From its openings ([`Split::from_openings`]).
    Openings,
    Given(Split),
}

/// Pool and reference sizes of the phantom and of meshes.
const POOL: usize = 40_000;
const REFERENCE: usize = 20_000;

impl StudyAtrium {
    /// The analytic phantom: pool and reference are independent exact samples (seeded), the
    /// split from its exact ostia.
    pub fn from_phantom(atrium: &Atrium, seed: u64) -> Result<Self, EamError> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let pool = atrium.surface_samples(POOL, &mut rng);
        let reference = atrium.surface_samples(REFERENCE, &mut rng).positions;
        let body = match atrium.body() {
            resecta_phantom::Solid::Ellipsoid { center, .. } => *center,
            resecta_phantom::Solid::Ball { center, .. } => *center,
            resecta_phantom::Solid::Capsule { a, b, .. } => (a + b) / 2.0,
        };
        let split = Split::from_ostia(body, &atrium.ostia(64))?;
        let n = pool.positions.len();
        let points = OrientedPoints {
            areas: vec![pool.area_per_sample; n],
            positions: pool.positions,
            normals: pool.normals,
        };
        Self::assemble("phantom".into(), points, reference, None, split)
    }

    /// A label map: the atrium is every body and vein label. The pool is its oriented points
    /// (Sobel, Paper I). The reference is its MCSD surface (Slicer's smoothing), sampled by
    /// area. The split comes from the vein labels' ostia unless `plane` is given.
    pub fn from_label_map(
        name: String,
        labels: &LabelMap,
        body_labels: &[u16],
        vein_labels: &[u16],
        plane: Option<Split>,
        seed: u64,
    ) -> Result<Self, EamError> {
        let counts = labels.value_counts();
        let absent: Vec<u16> = body_labels
            .iter()
            .chain(vein_labels)
            .copied()
            .filter(|l| !counts.contains_key(l))
            .collect();
        let present = |set: &[u16]| set.iter().any(|l| counts.contains_key(l));
        if !present(body_labels) || (plane.is_none() && !present(vein_labels)) {
            return Err(EamError::LabelsAbsent { labels: absent });
        }
        let mask = labels.map(|l| body_labels.contains(&l) || vein_labels.contains(&l));
        let pool = psr::points(&mask)?;
        let mesh = mcsd::reconstruct(&mask, &McsdParams::default())?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let reference = sample_mesh(&mesh, REFERENCE, &mut rng).positions;
        let split = match plane {
            Some(s) => s,
            None => label_split(labels, body_labels, vein_labels)?,
        };
        Self::assemble(name, pool, reference, Some(mesh), split)
    }

    /// A closed or open atrium mesh (outward normals expected; a mesh of negative signed volume
    /// is turned): pool and reference are independent area-uniform samples of it.
    pub fn from_mesh(
        name: String,
        mesh: &TriMesh,
        split: MeshSplit,
        seed: u64,
    ) -> Result<Self, EamError> {
        let split = match split {
            MeshSplit::Openings => Split::from_openings(mesh)?,
            MeshSplit::Given(s) => s,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut pool = sample_mesh(mesh, POOL, &mut rng);
        if mesh.signed_volume() < 0.0 {
            pool.normals.iter_mut().for_each(|n| *n = -*n);
        }
        let reference = sample_mesh(mesh, REFERENCE, &mut rng).positions;
        Self::assemble(name, pool, reference, Some(mesh.clone()), split)
    }

    fn assemble(
        name: String,
        pool: OrientedPoints,
        reference: Vec<Vec3>,
        reference_mesh: Option<TriMesh>,
        split: Split,
    ) -> Result<Self, EamError> {
        let upper: Vec<bool> = pool.positions.iter().map(|p| split.is_upper(p)).collect();
        let (mut ua, mut la) = (0.0, 0.0);
        let (mut un, mut ln) = (0, 0);
        for (&u, &a) in upper.iter().zip(&pool.areas) {
            if u {
                ua += a;
                un += 1;
            } else {
                la += a;
                ln += 1;
            }
        }
        if un == 0 || ln == 0 {
            return Err(EamError::EmptyPart {
                upper: un,
                lower: ln,
            });
        }
        Ok(Self {
            name,
            pool,
            upper,
            reference,
            reference_mesh,
            split,
            upper_area_mm2: ua,
            lower_area_mm2: la,
        })
    }

    /// The same atrium split by another plane.
    pub fn with_split(self, split: Split) -> Result<Self, EamError> {
        Self::assemble(
            self.name,
            self.pool,
            self.reference,
            self.reference_mesh,
            split,
        )
    }

    /// Pool points in the upper part.
    pub fn upper_count(&self) -> usize {
        self.upper.iter().filter(|&&u| u).count()
    }
}

/// The split of a label map from its vein labels' ostia: vein voxels with a face neighbour in
/// the body, and the body's centroid.
fn label_split(labels: &LabelMap, body: &[u16], veins: &[u16]) -> Result<Split, EamError> {
    let grid = labels.grid();
    let [nx, ny, nz] = grid.dims();
    let is_body = |ijk: [usize; 3]| labels.get(ijk).is_some_and(|l| body.contains(&l));
    let (sum, count, ostia) = (0..nz)
        .into_par_iter()
        .map(|k| {
            let mut sum = Vec3::zeros();
            let mut count = 0usize;
            let mut ostia: Vec<Vec<Vec3>> = vec![Vec::new(); veins.len()];
            for j in 0..ny {
                for i in 0..nx {
                    let l = labels.get([i, j, k]).unwrap_or(0);
                    if body.contains(&l) {
                        sum += grid.voxel_center([i, j, k]);
                        count += 1;
                    } else if let Some(v) = veins.iter().position(|&x| x == l) {
                        let touches = [
                            i.checked_sub(1).map(|i| [i, j, k]),
                            Some([i + 1, j, k]),
                            j.checked_sub(1).map(|j| [i, j, k]),
                            Some([i, j + 1, k]),
                            k.checked_sub(1).map(|k| [i, j, k]),
                            Some([i, j, k + 1]),
                        ]
                        .into_iter()
                        .flatten()
                        .any(is_body);
                        if touches {
                            ostia[v].push(grid.voxel_center([i, j, k]));
                        }
                    }
                }
            }
            (sum, count, ostia)
        })
        .reduce(
            || (Vec3::zeros(), 0, vec![Vec::new(); veins.len()]),
            |mut a, b| {
                a.0 += b.0;
                a.1 += b.1;
                for (x, y) in a.2.iter_mut().zip(b.2) {
                    x.extend(y);
                }
                a
            },
        );
    if count == 0 {
        return Err(EamError::LabelsAbsent {
            labels: body.to_vec(),
        });
    }
    Split::from_ostia(sum / count as Real, &ostia)
}

/// `count` area-uniform samples of `mesh` with its triangles' unit normals (each standing for
/// `area / count`).
pub fn sample_mesh(mesh: &TriMesh, count: usize, rng: &mut impl Rng) -> OrientedPoints {
    let mut cumulative = Vec::with_capacity(mesh.triangles().len());
    let mut total = 0.0;
    for t in 0..mesh.triangles().len() {
        let [a, b, c] = mesh.corners(t);
        total += 0.5 * (b - a).cross(&(c - a)).norm();
        cumulative.push(total);
    }
    let per = total / count.max(1) as Real;
    let mut out = OrientedPoints::default();
    if total <= 0.0 {
        return out;
    }
    for _ in 0..count {
        let x = rng.random::<Real>() * total;
        let t = cumulative
            .partition_point(|&c| c < x)
            .min(cumulative.len() - 1);
        let [a, b, c] = mesh.corners(t);
        let (r1, r2): (Real, Real) = (rng.random(), rng.random());
        let s = r1.sqrt();
        let p = a * (1.0 - s) + b * (s * (1.0 - r2)) + c * (s * r2);
        let n = (b - a).cross(&(c - a));
        let len = n.norm();
        if len > 0.0 {
            out.positions.push(p);
            out.normals.push(n / len);
            out.areas.push(per);
        }
    }
    out
}
