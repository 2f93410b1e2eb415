//! One plane of a label map resampled as a raster (the 2D slice views): nearest neighbour, since
//! labels are not interpolated, on any oblique anisotropic grid.
//!
//! The plane is axis-aligned in RAS; its in-plane axes are fixed: axial (RAS z = position)
//! columns +x rows +y, coronal (y) columns +x rows +z, sagittal (x) columns +y rows +z. The raster
//! covers the label map's RAS bounding box (of the voxel cubes' corners) projected on the plane,
//! from its low corner: pixel `(r, c)` is centred at `origin + c·pixel·column_axis +
//! r·pixel·row_axis`.

use resecta_geom::{Grid, LabelMap, Real, Vec3};

use crate::error::PlanError;

/// Most pixels of a label slice along either side.
pub const MAX_LABEL_SLICE_SIDE: usize = 1024;

/// Largest pixel size a label slice may be asked for, mm.
pub const MAX_LABEL_SLICE_PIXEL_MM: Real = 100.0;

/// The RAS axis a label slice's plane is normal to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SliceAxis {
    /// RAS z = position; columns +x, rows +y.
    Axial,
    /// RAS y = position; columns +x, rows +z.
    Coronal,
    /// RAS x = position; columns +y, rows +z.
    Sagittal,
}

impl SliceAxis {
    /// RAS coordinate indices of the normal, the columns and the rows.
    pub fn axes(self) -> [usize; 3] {
        match self {
            Self::Axial => [2, 0, 1],
            Self::Coronal => [1, 0, 2],
            Self::Sagittal => [0, 1, 2],
        }
    }
}

/// A resampled plane of a label map.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelSlice {
    pub width: usize,
    pub height: usize,
    /// Side of a (square) pixel, mm.
    pub pixel_mm: Real,
    /// RAS of the centre of pixel (0, 0).
    pub origin: Vec3,
    /// Unit RAS direction of increasing column.
    pub column_axis: Vec3,
    /// Unit RAS direction of increasing row.
    pub row_axis: Vec3,
    /// Row-major labels: pixel `(r, c)` at `r·width + c`; 0 outside the grid.
    pub labels: Vec<u16>,
    /// The label map's extent along the axis, mm (the positions a slice may be taken at).
    pub extent: [Real; 2],
}

/// Axis-aligned RAS bounds `(min, max)` of the voxel cubes' corners.
pub fn cube_bounds(grid: &Grid) -> (Vec3, Vec3) {
    let dims = grid.dims();
    let (mut lo, mut hi) = (
        Vec3::repeat(Real::INFINITY),
        Vec3::repeat(Real::NEG_INFINITY),
    );
    for corner in 0..8 {
        let ijk = Vec3::from_fn(|a, _| {
            if (corner >> a) & 1 == 0 {
                -0.5
            } else {
                dims[a] as Real - 0.5
            }
        });
        let p = grid.index_to_world(ijk);
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    }
    (lo, hi)
}

/// The plane of `labels` normal to `axis` at `position_mm`, with pixels of `pixel_mm` (absent:
/// the smallest voxel spacing), raised so that neither side exceeds [`MAX_LABEL_SLICE_SIDE`].
/// Refused: a position outside the label map's extent along the axis, a pixel size that is not
/// in (0, [`MAX_LABEL_SLICE_PIXEL_MM`]].
pub fn label_slice(
    labels: &LabelMap,
    axis: SliceAxis,
    position_mm: Real,
    pixel_mm: Option<Real>,
) -> Result<LabelSlice, PlanError> {
    let grid = labels.grid();
    let (lo, hi) = cube_bounds(grid);
    let [n, col, row] = axis.axes();
    let extent = [lo[n], hi[n]];
    if !(extent[0]..=extent[1]).contains(&position_mm) {
        return Err(PlanError::InvalidArgument(format!(
            "position_mm {position_mm} is outside the label map's extent along the axis, \
             [{}, {}] mm",
            extent[0], extent[1]
        )));
    }
    let asked = match pixel_mm {
        Some(p) if p > 0.0 && p <= MAX_LABEL_SLICE_PIXEL_MM => p,
        Some(p) => {
            return Err(PlanError::InvalidArgument(format!(
                "pixel_mm {p} is not in (0, {MAX_LABEL_SLICE_PIXEL_MM}]"
            )));
        }
        None => grid.spacing().into_iter().fold(Real::INFINITY, Real::min),
    };
    let side = MAX_LABEL_SLICE_SIDE as Real;
    let (span_c, span_r) = (hi[col] - lo[col], hi[row] - lo[row]);
    let pixel = asked.max(span_c / side).max(span_r / side);
    // A hair of slack so that a span of exactly `side` pixels is not rounded up to one more.
    let count = |span: Real| ((span / pixel - 1e-9).ceil() as usize).clamp(1, MAX_LABEL_SLICE_SIDE);
    let (width, height) = (count(span_c), count(span_r));
    let unit = |a: usize| Vec3::from_fn(|i, _| if i == a { 1.0 } else { 0.0 });
    let (column_axis, row_axis) = (unit(col), unit(row));
    let mut origin = lo + (column_axis + row_axis) * (pixel / 2.0);
    origin[n] = position_mm;
    // The continuous index is affine in (r, c): a start and two steps.
    let start = grid.world_to_index(origin);
    let step_c = grid.world_to_index(origin + column_axis * pixel) - start;
    let step_r = grid.world_to_index(origin + row_axis * pixel) - start;
    let dims = grid.dims();
    let data = labels.data();
    let mut out = vec![0u16; width * height];
    for (r, line) in out.chunks_exact_mut(width).enumerate() {
        let first = start + step_r * r as Real;
        for (c, px) in line.iter_mut().enumerate() {
            let q = first + step_c * c as Real;
            // The cubes' faces count as inside, so that the extent's ends sample the grid.
            let mut ijk = [0usize; 3];
            let inside = (0..3).all(|a| {
                let last = dims[a] as Real - 1.0;
                ijk[a] = q[a].round().clamp(0.0, last) as usize;
                (-0.5..=last + 0.5).contains(&q[a])
            });
            if inside {
                *px = data[grid.offset(ijk)];
            }
        }
    }
    Ok(LabelSlice {
        width,
        height,
        pixel_mm: pixel,
        origin,
        column_axis,
        row_axis,
        labels: out,
        extent,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use resecta_geom::{Mat3, Volume};
    use resecta_phantom::{
        EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate,
    };

    const CENTRE: [Real; 3] = [5.0, -3.0, 2.0];
    const RADIUS: Real = 20.0;
    const SPACING: [Real; 3] = [0.7, 0.9, 1.5];
    /// The tumour label of the phantoms' default role map.
    const TUMOUR: u16 = 2;

    /// A sphere (the tumour, label 2) in a liver (label 1) on an oblique anisotropic grid.
    fn sphere() -> LabelMap {
        let spec = PhantomSpec {
            grid: GridSpec::centred(
                [90, 80, 45],
                SPACING,
                [4.0, -2.0, 1.0],
                Orientation::EulerDeg([10.0, -8.0, 25.0]),
            ),
            liver: vec![EllipsoidSpec {
                center: CENTRE,
                radii: [28.0, 26.0, 25.0],
                rotation: Orientation::Identity,
            }],
            tumors: vec![SphereSpec {
                center: CENTRE,
                radius: RADIUS,
            }],
            vessels: Vec::new(),
            ..PhantomSpec::small()
        };
        generate(&spec).unwrap().labels
    }

    fn centre(s: &LabelSlice, r: usize, c: usize) -> Vec3 {
        s.origin + s.column_axis * (c as Real * s.pixel_mm) + s.row_axis * (r as Real * s.pixel_mm)
    }

    /// Half the diagonal of a voxel: how far a pixel centre may be from the voxel centre whose
    /// label it takes.
    fn half_diagonal() -> Real {
        SPACING.iter().map(|s| s * s).sum::<Real>().sqrt() / 2.0
    }

    #[test]
    fn the_sphere_slices_through_its_centre_to_a_disc_of_its_radius() {
        let labels = sphere();
        let h = half_diagonal();
        for (axis, n) in [
            (SliceAxis::Axial, 2),
            (SliceAxis::Coronal, 1),
            (SliceAxis::Sagittal, 0),
        ] {
            let s = label_slice(&labels, axis, CENTRE[n], Some(0.4)).unwrap();
            assert_eq!(s.pixel_mm, 0.4);
            let c = Vec3::from(CENTRE);
            let mut count = 0;
            for r in 0..s.height {
                for col in 0..s.width {
                    let d = (centre(&s, r, col) - c).norm();
                    let is_tumour = s.labels[r * s.width + col] == TUMOUR;
                    count += usize::from(is_tumour);
                    // Nearest neighbour: the voxel whose label a pixel takes has its centre
                    // within half a voxel diagonal of the pixel centre.
                    assert!(
                        !is_tumour || d <= RADIUS + h,
                        "{axis:?} ({r}, {col}) at {d}"
                    );
                    assert!(is_tumour || d >= RADIUS - h, "{axis:?} ({r}, {col}) at {d}");
                }
            }
            let area = count as Real * s.pixel_mm * s.pixel_mm;
            let disc = std::f64::consts::PI * RADIUS * RADIUS;
            assert!(
                (area / disc - 1.0).abs() < 0.03,
                "{axis:?}: {area} vs {disc}"
            );
        }
    }

    #[test]
    fn the_raster_covers_the_cube_bounds_with_the_documented_axes() {
        let labels = sphere();
        let (lo, hi) = cube_bounds(labels.grid());
        let s = label_slice(&labels, SliceAxis::Coronal, 0.0, None).unwrap();
        // Absent pixel size: the smallest spacing.
        assert_eq!(s.pixel_mm, 0.7);
        assert_eq!(s.column_axis, Vec3::x());
        assert_eq!(s.row_axis, Vec3::z());
        assert_eq!(s.extent, [lo.y, hi.y]);
        assert_eq!(s.width, ((hi.x - lo.x) / 0.7).ceil() as usize);
        assert_eq!(s.height, ((hi.z - lo.z) / 0.7).ceil() as usize);
        assert_eq!(s.origin, Vec3::new(lo.x + 0.35, 0.0, lo.z + 0.35));
        assert_eq!(s.labels.len(), s.width * s.height);
        // The corners are outside the oblique grid: background.
        assert_eq!(s.labels[0], 0);
        let sag = label_slice(&labels, SliceAxis::Sagittal, 1.0, None).unwrap();
        assert_eq!((sag.column_axis, sag.row_axis), (Vec3::y(), Vec3::z()));
        let ax = label_slice(&labels, SliceAxis::Axial, 1.0, None).unwrap();
        assert_eq!((ax.column_axis, ax.row_axis), (Vec3::x(), Vec3::y()));
    }

    #[test]
    fn a_point_label_lands_in_its_pixel_and_the_axes_point_the_documented_way() {
        let r = Orientation::EulerDeg([11.0, -9.0, 23.0])
            .matrix("grid")
            .unwrap();
        let grid = Grid::new([40, 30, 20], SPACING, Vec3::new(-12.0, -9.0, -14.0), r).unwrap();
        let mut labels = Volume::filled(grid.clone(), 0u16);
        // Balls of 2 mm: label 7 at a voxel centre, 8 six mm along +x from it, 9 along +y, 10
        // along +z; each must be seen on the side its axis says.
        let p = grid.voxel_center([20, 15, 10]);
        for (label, d) in [
            (7, Vec3::zeros()),
            (8, Vec3::x()),
            (9, Vec3::y()),
            (10, Vec3::z()),
        ] {
            for k in 0..grid.len() {
                let ijk = grid.ijk(k);
                if (grid.voxel_center(ijk) - p - d * 6.0).norm() <= 2.0 {
                    labels.set(ijk, label);
                }
            }
        }
        let mean = |s: &LabelSlice, label: u16| {
            let hits: Vec<(Real, Real)> = (0..s.labels.len())
                .filter(|&k| s.labels[k] == label)
                .map(|k| ((k / s.width) as Real, (k % s.width) as Real))
                .collect();
            assert!(!hits.is_empty(), "label {label} is on the slice");
            let n = hits.len() as Real;
            let (r, c) = hits.iter().fold((0.0, 0.0), |a, h| (a.0 + h.0, a.1 + h.1));
            (r / n, c / n)
        };
        for (axis, n, along_col, along_row) in [
            (SliceAxis::Axial, 2, 8, 9),
            (SliceAxis::Coronal, 1, 8, 10),
            (SliceAxis::Sagittal, 0, 9, 10),
        ] {
            let s = label_slice(&labels, axis, p[n], Some(0.25)).unwrap();
            // The pixel whose centre is nearest the point holds its label.
            let at = |a: Vec3| ((p - s.origin).dot(&a) / s.pixel_mm).round() as usize;
            let (r0, c0) = (at(s.row_axis), at(s.column_axis));
            assert_eq!(s.labels[r0 * s.width + c0], 7, "{axis:?}");
            let (r7, c7) = mean(&s, 7);
            let (rc, cc) = mean(&s, along_col);
            let (rr, cr) = mean(&s, along_row);
            // 6 mm is 24 pixels; the discs' voxel outlines move their centroids by under 3.
            assert!(
                (cc - c7 - 24.0).abs() < 3.0 && (rc - r7).abs() < 3.0,
                "{axis:?}"
            );
            assert!(
                (rr - r7 - 24.0).abs() < 3.0 && (cr - c7).abs() < 3.0,
                "{axis:?}"
            );
        }
    }

    #[test]
    fn positions_and_pixel_sizes_out_of_range_are_refused_and_big_rasters_coarsened() {
        let g = Grid::new(
            [600, 10, 3],
            [2.0, 1.0, 1.0],
            Vec3::zeros(),
            Mat3::identity(),
        )
        .unwrap();
        let labels = Volume::filled(g, 1u16);
        // Cube bounds along z: [-0.5, 2.5].
        let e = label_slice(&labels, SliceAxis::Axial, 2.6, None).unwrap_err();
        assert_eq!(
            e.to_string(),
            "position_mm 2.6 is outside the label map's extent along the axis, [-0.5, 2.5] mm"
        );
        assert!(label_slice(&labels, SliceAxis::Axial, Real::NAN, None).is_err());
        for p in [0.0, -1.0, 100.5, Real::NAN, Real::INFINITY] {
            let e = label_slice(&labels, SliceAxis::Axial, 2.5, Some(p)).unwrap_err();
            assert!(e.to_string().starts_with("pixel_mm"), "{e}");
        }
        // 1200 mm along x at 1 mm would be 1200 columns: the pixel grows to fit 1024.
        let s = label_slice(&labels, SliceAxis::Axial, -0.5, None).unwrap();
        assert_eq!(s.pixel_mm, 1200.0 / 1024.0);
        assert_eq!((s.width, s.height), (1024, 9));
        assert!(s.labels.iter().all(|&l| l == 1));
    }
}
