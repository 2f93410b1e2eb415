//! Order statistics.

use resecta_geom::Real;

/// Percentile `pct` ∈ [0, 100] of `sorted` (ascending, finite) by linear interpolation between
/// closest ranks (NumPy's default, Hyndman–Fan type 7): rank `pct/100 · (n − 1)`. `None` when
/// `sorted` is empty or `pct` is outside [0, 100].
pub fn percentile(sorted: &[Real], pct: Real) -> Option<Real> {
    if sorted.is_empty() || !(0.0..=100.0).contains(&pct) {
        return None;
    }
    let rank = pct / 100.0 * (sorted.len() - 1) as Real;
    let lo = rank.floor() as usize;
    let hi = rank.ceil() as usize;
    let (a, b) = (sorted[lo], sorted[hi.min(sorted.len() - 1)]);
    Some(a + (b - a) * (rank - lo as Real))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_interpolates_like_numpy() {
        let v = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(percentile(&v, 0.0), Some(1.0));
        assert_eq!(percentile(&v, 100.0), Some(5.0));
        assert_eq!(percentile(&v, 50.0), Some(3.0));
        // numpy.percentile([1,2,3,4,5], 95) = 4.8
        assert!((percentile(&v, 95.0).unwrap() - 4.8).abs() < 1e-12);
        assert_eq!(percentile(&[7.0], 37.0), Some(7.0));
        assert_eq!(percentile(&[], 50.0), None);
        assert_eq!(percentile(&v, 101.0), None);
        assert_eq!(percentile(&v, Real::NAN), None);
    }
}
