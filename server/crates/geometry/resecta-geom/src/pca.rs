//! Principal component analysis of point sets (contours, meshes).

use crate::error::GeomError;
use crate::math::{Mat3, Real, Vec3};

/// Mean, eigenvalues (descending, population covariance) and unit axes of a point set.
#[derive(Debug, Clone, PartialEq)]
pub struct Pca {
    pub mean: Vec3,
    /// Variances along `axes`, largest first.
    pub eigenvalues: [Real; 3],
    /// Unit principal axes matching `eigenvalues`; a right-handed frame.
    pub axes: [Vec3; 3],
}

impl Pca {
    /// PCA of `points` (at least one point).
    pub fn of_points(points: &[Vec3]) -> Result<Self, GeomError> {
        if points.is_empty() {
            return Err(GeomError::TooFewPoints { needed: 1, got: 0 });
        }
        let n = points.len() as Real;
        let mean = points.iter().sum::<Vec3>() / n;
        let cov = points.iter().fold(Mat3::zeros(), |acc, p| {
            let d = p - mean;
            acc + d * d.transpose()
        }) / n;
        Ok(Self::from_covariance(mean, cov))
    }

    /// PCA from a mean and a symmetric covariance matrix.
    pub fn from_covariance(mean: Vec3, cov: Mat3) -> Self {
        let eig = cov.symmetric_eigen();
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let axis = |i: usize| -> Vec3 { eig.eigenvectors.column(order[i]).into_owned() };
        let (a0, a1) = (axis(0), axis(1));
        let eigenvalues = order.map(|i| eig.eigenvalues[i].max(0.0));
        Self {
            mean,
            eigenvalues,
            axes: [a0, a1, a0.cross(&a1)],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn recovers_axes_of_a_stretched_cloud() {
        let u = Vec3::new(1.0, 1.0, 0.0).normalize();
        let v = Vec3::new(-1.0, 1.0, 0.0).normalize();
        let mut pts = Vec::new();
        for i in -10..=10 {
            for j in -3..=3 {
                pts.push(Vec3::new(5.0, -2.0, 1.0) + u * f64::from(i) * 2.0 + v * f64::from(j));
            }
        }
        let pca = Pca::of_points(&pts).unwrap();
        assert_relative_eq!(pca.mean, Vec3::new(5.0, -2.0, 1.0), epsilon = 1e-12);
        assert_relative_eq!(pca.axes[0].dot(&u).abs(), 1.0, epsilon = 1e-12);
        assert_relative_eq!(pca.axes[1].dot(&v).abs(), 1.0, epsilon = 1e-12);
        // Var of 2·i for i in -10..=10 is 4·770/21; of j in -3..=3 it is 4.
        assert_relative_eq!(pca.eigenvalues[0], 4.0 * 770.0 / 21.0, epsilon = 1e-9);
        assert_relative_eq!(pca.eigenvalues[1], 4.0, epsilon = 1e-9);
        assert_relative_eq!(pca.eigenvalues[2], 0.0, epsilon = 1e-9);
        assert_relative_eq!(
            pca.axes[0].cross(&pca.axes[1]).dot(&pca.axes[2]),
            1.0,
            epsilon = 1e-12
        );
        assert!(Pca::of_points(&[]).is_err());
    }
}
