//! Initial resection (thesis Sec. 7.3.2, Algorithms 1–2): the plane through the midpoint of the
//! tumour centroid and a user end point, the parenchyma's contour on it, the contour's principal
//! axes and a planar m×n control grid of extent l_i = 4·√e_i centred on the contour.

use resecta_geom::{Mat3, Plane, Polyline, Real, TriMesh, Vec3, slice};
use serde::Serialize;

use crate::error::PlanError;
use crate::resection::{MAX_COORDINATE_MM, MIN_CONTROL_POINTS, arr, check_point};

/// Contours shorter than this (mm) do not define a resection.
const MIN_CONTOUR_MM: Real = 1.0;

/// End points closer than this (mm) to the tumour centroid do not define a direction.
pub const MIN_END_DISTANCE_MM: Real = 1.0;

/// Eq. 7.5: the plane through (c + p_e)/2 with normal p_e − c.
pub fn slicing_plane(tumour_centroid: Vec3, end_point: Vec3) -> Result<Plane, PlanError> {
    check_point(|| "end point".into(), arr(end_point))?;
    check_point(|| "tumour centroid".into(), arr(tumour_centroid))?;
    let n = end_point - tumour_centroid;
    if n.norm() < MIN_END_DISTANCE_MM {
        return Err(PlanError::EndPointAtCentroid);
    }
    Ok(Plane::new((tumour_centroid + end_point) / 2.0, n)?)
}

/// A plane from a point and a normal (scripted use).
pub fn plane_from(point: Vec3, normal: Vec3) -> Result<Plane, PlanError> {
    check_point(|| "plane point".into(), arr(point))?;
    check_point(|| "plane normal".into(), arr(normal))?;
    Plane::new(point, normal)
        .map_err(|_| PlanError::InvalidArgument("plane normal must be non-zero".into()))
}

/// The initial resection on a plane.
#[derive(Debug, Clone, Serialize)]
pub struct Initialisation {
    /// Point and unit normal of the slicing plane; the normal points away from the tumour.
    pub plane_point: [Real; 3],
    pub plane_normal: [Real; 3],
    /// The parenchyma contour V_s (one polyline per loop).
    #[serde(skip)]
    pub contour: Vec<Polyline>,
    /// Centroid of the contour (Eq. 7.7, length-weighted).
    pub centre: [Real; 3],
    /// In-plane principal axes E1, E2 (E1 × E2 = plane normal).
    pub axes: [[Real; 3]; 2],
    /// Eigenvalues e1 ≥ e2 of the contour's covariance (mm²).
    pub eigenvalues: [Real; 2],
    /// Extents l_i = 4·√e_i (Eq. 7.6).
    pub lengths: [Real; 2],
    /// m·n control points, row-major (i along E1, j along E2).
    pub control_points: Vec<[Real; 3]>,
}

/// Algorithm 1 + 2: slices `parenchyma` with `plane` and builds the m×n planar grid.
///
/// The contour's mean and covariance are those of a uniform distribution along its segments
/// (vertices of a mesh slice are unevenly spaced). The grid spans
/// `o + (i/(m−1))·l1·E1 + (j/(n−1))·l2·E2` with `o = c − l1/2·E1 − l2/2·E2`, so its corners are
/// exactly the thesis' extent (Algorithm 2 as printed steps by l/m and misses one column).
pub fn initialise(
    parenchyma: &TriMesh,
    plane: &Plane,
    grid: [usize; 2],
) -> Result<Initialisation, PlanError> {
    let [m, n] = grid;
    let sides = MIN_CONTROL_POINTS..=resecta_bezier::MAX_CONTROL_POINTS;
    if !sides.contains(&m) || !sides.contains(&n) {
        return Err(PlanError::InvalidArgument(format!(
            "grid {m}×{n}: each side must be {MIN_CONTROL_POINTS}..={}",
            resecta_bezier::MAX_CONTROL_POINTS
        )));
    }
    let contour = slice(parenchyma, plane);
    let (length, mean, cov) = segment_moments(&contour);
    if length < MIN_CONTOUR_MM {
        return Err(PlanError::PlaneMissesLiver);
    }
    let normal = plane.normal;
    // An in-plane orthonormal basis, then the 2×2 covariance and its eigenvectors.
    let a = normal.cross(&helper_axis(&normal)).normalize();
    let b = normal.cross(&a);
    let (caa, cab, cbb) = (a.dot(&(cov * a)), a.dot(&(cov * b)), b.dot(&(cov * b)));
    let half_trace = (caa + cbb) / 2.0;
    let root = (((caa - cbb) / 2.0).powi(2) + cab * cab).sqrt();
    let (e1, e2) = (half_trace + root, (half_trace - root).max(0.0));
    let theta = 0.5 * (2.0 * cab).atan2(caa - cbb);
    let mut ax1 = a * theta.cos() + b * theta.sin();
    // Deterministic sign: the largest component of E1 is positive.
    let k = ax1.iamax();
    if ax1[k] < 0.0 {
        ax1 = -ax1;
    }
    let ax2 = normal.cross(&ax1);
    let (l1, l2) = (4.0 * e1.sqrt(), 4.0 * e2.sqrt());
    if l2 < MIN_CONTOUR_MM {
        return Err(PlanError::PlaneMissesLiver);
    }
    let origin = mean - ax1 * (l1 / 2.0) - ax2 * (l2 / 2.0);
    let control_points: Vec<[Real; 3]> = (0..m * n)
        .map(|k| {
            let (i, j) = (k / n, k % n);
            let s = i as Real / (m - 1) as Real;
            let t = j as Real / (n - 1) as Real;
            arr(origin + ax1 * (s * l1) + ax2 * (t * l2))
        })
        .collect();
    if control_points
        .iter()
        .flatten()
        .any(|c| !c.is_finite() || c.abs() > MAX_COORDINATE_MM)
    {
        return Err(PlanError::InvalidArgument(
            "initial grid is not finite".into(),
        ));
    }
    Ok(Initialisation {
        plane_point: arr(plane.point),
        plane_normal: arr(normal),
        contour,
        centre: arr(mean),
        axes: [arr(ax1), arr(ax2)],
        eigenvalues: [e1, e2],
        lengths: [l1, l2],
        control_points,
    })
}

/// A unit axis not parallel to `n`.
fn helper_axis(n: &Vec3) -> Vec3 {
    let k = n.iamin();
    let mut e = Vec3::zeros();
    e[k] = 1.0;
    e
}

/// Length, mean and covariance of the uniform distribution along the polylines' segments.
fn segment_moments(lines: &[Polyline]) -> (Real, Vec3, Mat3) {
    let mut length = 0.0;
    let mut first = Vec3::zeros();
    let mut second = Mat3::zeros();
    for (p, q) in lines.iter().flat_map(Polyline::segments) {
        let l = (q - p).norm();
        length += l;
        first += (p + q) * (l / 2.0);
        // ∫ x xᵀ over the segment = l·(p pᵀ + q qᵀ)/3 + l·(p qᵀ + q pᵀ)/6.
        second += (p * p.transpose() + q * q.transpose()) * (l / 3.0)
            + (p * q.transpose() + q * p.transpose()) * (l / 6.0);
    }
    if length <= 0.0 {
        return (0.0, Vec3::zeros(), Mat3::zeros());
    }
    let mean = first / length;
    (length, mean, second / length - mean * mean.transpose())
}
