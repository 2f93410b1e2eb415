//! Discrete Gaussian curvature (Eq. 6.13).
//!
//! At vertex `p`, `K(p) = 3·(2π − Σγ) / A(p)`: the angle deficit over one third of the area of the
//! incident triangles (the barycentric area of `p`), which converges to the Gaussian curvature
//! (1/r² on a sphere of radius r; its sum weighted by A/3 over a closed genus-0 mesh is 4π by the
//! discrete Gauss–Bonnet theorem).
//!
//! Boundary vertices: the deficit `2π − Σγ` only measures curvature where the incident triangles
//! close a full fan. A vertex on a boundary edge (used by one triangle) or a non-manifold edge (used
//! by more than two) has no defined value and is left out, as is a vertex with no triangle or with
//! zero incident area. Closed models (all of Paper I's) have none of these.

use resecta_geom::{Real, TriMesh, Vec3};

use crate::error::MetricsError;
use crate::stats::percentile;

/// Eq. 6.13 at every vertex, in 1/mm²; `None` where undefined (see the module documentation).
/// Sequential and deterministic.
pub fn vertex_gaussian_curvature(mesh: &TriMesh) -> Result<Vec<Option<Real>>, MetricsError> {
    if mesh.is_empty() {
        return Err(MetricsError::EmptyMesh);
    }
    let n = mesh.vertices().len();
    let tris = mesh.triangles();
    let mut angle = vec![0.0 as Real; n];
    let mut area = vec![0.0 as Real; n];
    let mut open = vec![false; n];
    let mut used = vec![false; n];
    for (t, tri) in tris.iter().enumerate() {
        let c = mesh.corners(t);
        let a = 0.5 * (c[1] - c[0]).cross(&(c[2] - c[0])).norm();
        for k in 0..3 {
            let v = tri[k] as usize;
            angle[v] += corner_angle(&c[k], &c[(k + 1) % 3], &c[(k + 2) % 3]);
            area[v] += a;
            used[v] = true;
        }
    }
    // Undirected edges, sorted: runs of length ≠ 2 are boundary or non-manifold edges.
    let mut edges: Vec<(u32, u32)> = tris
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    edges.sort_unstable();
    for run in edges.chunk_by(|a, b| a == b) {
        if run.len() != 2 {
            open[run[0].0 as usize] = true;
            open[run[0].1 as usize] = true;
        }
    }
    Ok((0..n)
        .map(|v| {
            (used[v] && !open[v] && area[v] > 0.0)
                .then(|| 3.0 * (std::f64::consts::TAU - angle[v]) / area[v])
        })
        .collect())
}

/// Interior angle at `p` of the triangle (p, q, r), robust for small and obtuse angles.
fn corner_angle(p: &Vec3, q: &Vec3, r: &Vec3) -> Real {
    let (u, w) = (q - p, r - p);
    u.cross(&w).norm().atan2(u.dot(&w))
}

/// Mean of Eq. 6.13 over the vertices whose value lies within the `[lo_pct, hi_pct]` percentiles
/// (inclusive, [`percentile`] by linear interpolation) of all defined vertex values; 5 and 95 in
/// the thesis (Table 6.4). If the band holds no value (possible only for a band narrower than one
/// rank), the midpoint of its two percentile values is returned.
pub fn mean_gaussian_curvature(
    mesh: &TriMesh,
    lo_pct: Real,
    hi_pct: Real,
) -> Result<Real, MetricsError> {
    if !(0.0..=100.0).contains(&lo_pct) || !(lo_pct..=100.0).contains(&hi_pct) {
        return Err(MetricsError::BadPercentiles {
            lo: lo_pct,
            hi: hi_pct,
        });
    }
    let mut k: Vec<Real> = vertex_gaussian_curvature(mesh)?
        .into_iter()
        .flatten()
        .collect();
    k.sort_unstable_by(Real::total_cmp);
    let (Some(lo), Some(hi)) = (percentile(&k, lo_pct), percentile(&k, hi_pct)) else {
        return Err(MetricsError::NoCurvature);
    };
    let (sum, count) = k
        .iter()
        .filter(|&&v| lo <= v && v <= hi)
        .fold((0.0, 0usize), |(s, c), &v| (s + v, c + 1));
    Ok(if count == 0 {
        0.5 * (lo + hi)
    } else {
        sum / count as Real
    })
}
