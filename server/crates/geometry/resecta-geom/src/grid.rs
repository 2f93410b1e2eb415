//! Voxel grids with their full index→RAS affine, and volumes of voxel values on them.

use std::collections::BTreeMap;

use crate::error::GeomError;
use crate::math::{Mat3, Mat4, Real, Vec3};

/// Largest number of voxels a grid may hold; checked before anything is allocated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VoxelLimit(pub u64);

impl Default for VoxelLimit {
    /// 1024³ voxels.
    fn default() -> Self {
        Self(1 << 30)
    }
}

impl VoxelLimit {
    /// Checks `dims` against the limit without overflowing.
    pub fn check(self, dims: [usize; 3]) -> Result<usize, GeomError> {
        if dims.contains(&0) {
            return Err(GeomError::EmptyDims(dims));
        }
        let too_many = GeomError::TooManyVoxels {
            dims,
            limit: self.0,
        };
        let n = dims
            .iter()
            .try_fold(1u64, |acc, &d| acc.checked_mul(d as u64))
            .ok_or_else(|| too_many.clone())?;
        if n > self.0 {
            return Err(too_many);
        }
        usize::try_from(n).map_err(|_| too_many)
    }
}

/// The geometry of a voxel grid: `world = origin + direction · diag(spacing) · ijk`, in RAS mm.
///
/// Index `(i, j, k)` is a voxel centre; `i` varies fastest in memory. The direction matrix has unit
/// columns (the world directions of the i, j, k axes); it may be oblique and, for sheared sforms,
/// non-orthogonal, but never singular.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    dims: [usize; 3],
    spacing: [Real; 3],
    origin: Vec3,
    direction: Mat3,
    /// `direction · diag(spacing)`.
    linear: Mat3,
    inverse: Mat3,
}

impl Grid {
    /// A validated grid under the default [`VoxelLimit`].
    pub fn new(
        dims: [usize; 3],
        spacing: [Real; 3],
        origin: Vec3,
        direction: Mat3,
    ) -> Result<Self, GeomError> {
        Self::with_limit(dims, spacing, origin, direction, VoxelLimit::default())
    }

    /// An axis-aligned grid with identity direction.
    pub fn axis_aligned(
        dims: [usize; 3],
        spacing: [Real; 3],
        origin: Vec3,
    ) -> Result<Self, GeomError> {
        Self::new(dims, spacing, origin, Mat3::identity())
    }

    /// A validated grid; `direction` columns are normalised here.
    pub fn with_limit(
        dims: [usize; 3],
        spacing: [Real; 3],
        origin: Vec3,
        direction: Mat3,
        limit: VoxelLimit,
    ) -> Result<Self, GeomError> {
        limit.check(dims)?;
        if spacing.iter().any(|s| !s.is_finite() || *s <= 0.0) {
            return Err(GeomError::BadSpacing(spacing));
        }
        if origin.iter().any(|o| !o.is_finite()) {
            return Err(GeomError::BadOrigin(origin.into()));
        }
        if direction.iter().any(|d| !d.is_finite()) {
            return Err(GeomError::SingularDirection);
        }
        let mut dir = direction;
        for mut c in dir.column_iter_mut() {
            let n = c.norm();
            if n < 1e-12 {
                return Err(GeomError::SingularDirection);
            }
            c /= n;
        }
        // Nearly parallel axes make world→index ill-conditioned: refuse them.
        if dir.determinant().abs() < 1e-6 {
            return Err(GeomError::SingularDirection);
        }
        let linear = dir * Mat3::from_diagonal(&Vec3::from(spacing));
        let inverse = linear.try_inverse().ok_or(GeomError::SingularDirection)?;
        Ok(Self {
            dims,
            spacing,
            origin,
            direction: dir,
            linear,
            inverse,
        })
    }

    /// A grid from a 4×4 index→RAS affine: spacing is the column norms, direction the unit columns.
    pub fn from_affine(
        dims: [usize; 3],
        affine: &Mat4,
        limit: VoxelLimit,
    ) -> Result<Self, GeomError> {
        let m: Mat3 = affine.fixed_view::<3, 3>(0, 0).into_owned();
        let origin: Vec3 = affine.fixed_view::<3, 1>(0, 3).into_owned();
        let spacing = [m.column(0).norm(), m.column(1).norm(), m.column(2).norm()];
        Self::with_limit(dims, spacing, origin, m, limit)
    }

    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }
    pub fn spacing(&self) -> [Real; 3] {
        self.spacing
    }
    pub fn origin(&self) -> Vec3 {
        self.origin
    }
    /// Unit world directions of the i, j, k axes, as columns.
    pub fn direction(&self) -> Mat3 {
        self.direction
    }
    /// `direction · diag(spacing)`: index steps to world millimetres.
    pub fn linear(&self) -> Mat3 {
        self.linear
    }

    /// The inverse of [`Grid::linear`]: world millimetres to index steps.
    pub fn inverse_linear(&self) -> Mat3 {
        self.inverse
    }

    /// The 4×4 index→RAS affine.
    pub fn affine(&self) -> Mat4 {
        let mut m = Mat4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.linear);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.origin);
        m
    }

    /// Number of voxels (fits in `usize`, checked at construction).
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    /// Never true: a grid has at least one voxel.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Volume of one voxel in mm³ (|det| of the linear part, right for sheared grids too).
    pub fn voxel_volume_mm3(&self) -> Real {
        self.linear.determinant().abs()
    }

    /// Whether the axes are mutually orthogonal (to 1e-6), as distance transforms assume.
    pub fn is_orthogonal(&self) -> bool {
        let g = self.direction.transpose() * self.direction;
        (g - Mat3::identity()).abs().max() < 1e-6
    }

    /// Continuous index (voxel centres at integers) → RAS mm.
    pub fn index_to_world(&self, ijk: Vec3) -> Vec3 {
        self.origin + self.linear * ijk
    }

    /// RAS mm → continuous index.
    pub fn world_to_index(&self, p: Vec3) -> Vec3 {
        self.inverse * (p - self.origin)
    }

    /// Centre of voxel `(i, j, k)` in RAS mm.
    pub fn voxel_center(&self, ijk: [usize; 3]) -> Vec3 {
        self.index_to_world(Vec3::new(ijk[0] as Real, ijk[1] as Real, ijk[2] as Real))
    }

    /// Linear offset of `(i, j, k)`, `i` fastest. Caller guarantees the index is inside.
    #[inline]
    pub fn offset(&self, ijk: [usize; 3]) -> usize {
        ijk[0] + self.dims[0] * (ijk[1] + self.dims[1] * ijk[2])
    }

    /// `(i, j, k)` of a linear offset.
    #[inline]
    pub fn ijk(&self, offset: usize) -> [usize; 3] {
        let [nx, ny, _] = self.dims;
        [offset % nx, (offset / nx) % ny, offset / (nx * ny)]
    }

    /// Whether `(i, j, k)` lies in the grid.
    pub fn contains(&self, ijk: [usize; 3]) -> bool {
        ijk.iter().zip(self.dims).all(|(&a, d)| a < d)
    }

    /// Axis-aligned RAS bounds `(min, max)` of the voxel centres.
    pub fn world_bounds(&self) -> (Vec3, Vec3) {
        let hi = self.dims.map(|d| (d - 1) as Real);
        let mut lo = Vec3::repeat(Real::INFINITY);
        let mut up = Vec3::repeat(Real::NEG_INFINITY);
        for c in 0..8 {
            let ijk = Vec3::new(
                if c & 1 == 0 { 0.0 } else { hi[0] },
                if c & 2 == 0 { 0.0 } else { hi[1] },
                if c & 4 == 0 { 0.0 } else { hi[2] },
            );
            let p = self.index_to_world(ijk);
            lo = lo.inf(&p);
            up = up.sup(&p);
        }
        (lo, up)
    }
}

/// Voxel values on a [`Grid`], `i` fastest.
#[derive(Debug, Clone, PartialEq)]
pub struct Volume<T> {
    grid: Grid,
    data: Vec<T>,
}

impl<T: Copy> Volume<T> {
    /// A volume with every voxel set to `value`.
    pub fn filled(grid: Grid, value: T) -> Self {
        let data = vec![value; grid.len()];
        Self { grid, data }
    }

    /// A volume from data in `i`-fastest order; the length must match the grid.
    pub fn from_vec(grid: Grid, data: Vec<T>) -> Result<Self, GeomError> {
        if data.len() != grid.len() {
            return Err(GeomError::DataLength {
                expected: grid.len(),
                got: data.len(),
            });
        }
        Ok(Self { grid, data })
    }

    pub fn grid(&self) -> &Grid {
        &self.grid
    }
    pub fn data(&self) -> &[T] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }
    pub fn into_data(self) -> Vec<T> {
        self.data
    }

    /// Value at `(i, j, k)`, or `None` outside the grid.
    pub fn get(&self, ijk: [usize; 3]) -> Option<T> {
        self.grid
            .contains(ijk)
            .then(|| self.data[self.grid.offset(ijk)])
    }

    /// Sets `(i, j, k)`; returns false (and changes nothing) outside the grid.
    pub fn set(&mut self, ijk: [usize; 3], value: T) -> bool {
        if !self.grid.contains(ijk) {
            return false;
        }
        let o = self.grid.offset(ijk);
        self.data[o] = value;
        true
    }

    /// A volume of `f(value)` on the same grid.
    pub fn map<U: Copy>(&self, f: impl Fn(T) -> U) -> Volume<U> {
        Volume {
            grid: self.grid.clone(),
            data: self.data.iter().map(|&v| f(v)).collect(),
        }
    }
}

impl<T: Copy + Ord> Volume<T> {
    /// Voxel count of every distinct value.
    pub fn value_counts(&self) -> BTreeMap<T, u64> {
        let mut counts = BTreeMap::new();
        for &v in &self.data {
            *counts.entry(v).or_insert(0) += 1;
        }
        counts
    }
}

/// A label map: one label value per voxel, 0 = background.
pub type LabelMap = Volume<u16>;

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::Rotation3;

    fn oblique() -> Grid {
        let r = Rotation3::from_euler_angles(0.3, -0.2, 0.7).into_inner();
        Grid::new(
            [10, 20, 30],
            [0.8, 0.8, 2.5],
            Vec3::new(-100.0, 50.0, 7.0),
            r,
        )
        .unwrap()
    }

    #[test]
    fn world_index_round_trip_on_oblique_anisotropic_grid() {
        let g = oblique();
        let ijk = Vec3::new(3.25, 17.5, 29.0);
        let w = g.index_to_world(ijk);
        assert_relative_eq!(g.world_to_index(w), ijk, epsilon = 1e-10);
        // One step along k moves 2.5 mm.
        let d = g.index_to_world(ijk + Vec3::z()) - w;
        assert_relative_eq!(d.norm(), 2.5, epsilon = 1e-12);
        assert_relative_eq!(g.voxel_volume_mm3(), 0.8 * 0.8 * 2.5, epsilon = 1e-12);
        assert!(g.is_orthogonal());
    }

    #[test]
    fn affine_round_trip() {
        let g = oblique();
        let back = Grid::from_affine(g.dims(), &g.affine(), VoxelLimit::default()).unwrap();
        assert_relative_eq!(back.linear(), g.linear(), epsilon = 1e-12);
        assert_relative_eq!(back.origin(), g.origin(), epsilon = 1e-12);
    }

    #[test]
    fn offsets_are_i_fastest() {
        let g = oblique();
        assert_eq!(g.offset([1, 0, 0]), 1);
        assert_eq!(g.offset([0, 1, 0]), 10);
        assert_eq!(g.offset([0, 0, 1]), 200);
        assert_eq!(g.ijk(g.offset([7, 13, 21])), [7, 13, 21]);
    }

    #[test]
    fn bad_grids_are_refused() {
        let id = Mat3::identity();
        let z = Vec3::zeros();
        assert!(matches!(
            Grid::new([0, 1, 1], [1.0; 3], z, id),
            Err(GeomError::EmptyDims(_))
        ));
        assert!(matches!(
            Grid::new([1 << 40, 1 << 40, 1 << 40], [1.0; 3], z, id),
            Err(GeomError::TooManyVoxels { .. })
        ));
        assert!(matches!(
            Grid::new([2048, 1024, 1024], [1.0; 3], z, id),
            Err(GeomError::TooManyVoxels { .. })
        ));
        for s in [0.0, -1.0, Real::NAN, Real::INFINITY] {
            assert!(matches!(
                Grid::new([1, 1, 1], [1.0, s, 1.0], z, id),
                Err(GeomError::BadSpacing(_))
            ));
        }
        let mut sing = id;
        sing.set_column(2, &Vec3::x());
        assert_eq!(
            Grid::new([1, 1, 1], [1.0; 3], z, sing),
            Err(GeomError::SingularDirection)
        );
        assert!(matches!(
            Grid::new([1, 1, 1], [1.0; 3], Vec3::new(Real::NAN, 0.0, 0.0), id),
            Err(GeomError::BadOrigin(_))
        ));
    }

    #[test]
    fn volume_access_and_counts() {
        let g = Grid::axis_aligned([4, 3, 2], [1.0; 3], Vec3::zeros()).unwrap();
        assert!(Volume::from_vec(g.clone(), vec![0u16; 5]).is_err());
        let mut v = Volume::filled(g, 0u16);
        assert!(v.set([3, 2, 1], 7));
        assert!(!v.set([4, 0, 0], 7));
        assert_eq!(v.get([3, 2, 1]), Some(7));
        assert_eq!(v.get([0, 3, 0]), None);
        let counts = v.value_counts();
        assert_eq!(counts[&0], 23);
        assert_eq!(counts[&7], 1);
    }
}
