//! Uploaded label maps: raw voxels or image files to a validated `u16` [`LabelMap`], its summary,
//! and its storage form (a JSON header and little-endian `u16` voxels).

use rayon::prelude::*;
use resecta_geom::{Grid, LabelMap, Mat3, Real, Role, RoleMap, Vec3, Volume, VoxelLimit};
use resecta_io::{metaimage, nifti, nrrd};
use serde::{Deserialize, Serialize};

use crate::api::{DataType, FileFormat, LabelMapSource, LabelMapSummary, RawLabelMap};
use crate::error::{Quota, Result, SessionError};

/// Name used in errors for uploaded files (never the client's file name: patient data).
const UPLOAD: &str = "uploaded label map";

fn invalid(m: impl Into<String>) -> SessionError {
    SessionError::BadLabelMap(m.into())
}

/// Voxel spacings a label map may have (mm): finer than a micrometre or coarser than 10 cm is
/// no patient image, and would overflow volumes or distance fields downstream.
pub const SPACING_MM: std::ops::RangeInclusive<Real> = 1e-3..=100.0;
/// Longest side of a label map (mm).
pub const MAX_EXTENT_MM: Real = 5000.0;
/// Farthest a label map's origin may lie from the scanner's origin (mm).
pub const MAX_ORIGIN_MM: Real = 1.0e5;

/// The label map of an upload, checked against `max_voxels` and physical bounds.
pub fn decode(source: &LabelMapSource, max_voxels: u64) -> Result<LabelMap> {
    let limit = VoxelLimit(max_voxels);
    let labels = match source {
        LabelMapSource::Raw(raw) => from_raw(raw, limit),
        LabelMapSource::File { format, bytes } => from_file(*format, bytes, limit),
    }?;
    check_physical(labels.grid())?;
    Ok(labels)
}

/// Refuses a geometry outside physical bounds ([`SPACING_MM`], [`MAX_EXTENT_MM`],
/// [`MAX_ORIGIN_MM`]), naming the field and axis.
pub fn check_physical(g: &Grid) -> Result<()> {
    let (spacing, dims, origin) = (g.spacing(), g.dims(), g.origin());
    for axis in 0..3 {
        let s = spacing[axis];
        if !SPACING_MM.contains(&s) {
            return Err(invalid(format!(
                "voxel spacing {s:e} mm along axis {axis} is outside {:e}..={} mm",
                SPACING_MM.start(),
                SPACING_MM.end()
            )));
        }
        let extent = s * dims[axis] as Real;
        if extent > MAX_EXTENT_MM {
            return Err(invalid(format!(
                "extent {extent:.0} mm along axis {axis} exceeds {MAX_EXTENT_MM} mm"
            )));
        }
        if !(-MAX_ORIGIN_MM..=MAX_ORIGIN_MM).contains(&origin[axis]) {
            return Err(invalid(format!(
                "origin {:e} mm along axis {axis} is beyond ±{MAX_ORIGIN_MM:e} mm",
                origin[axis]
            )));
        }
    }
    Ok(())
}

fn grid(
    dims: [usize; 3],
    spacing: [Real; 3],
    origin: [Real; 3],
    direction: [Real; 9],
    limit: VoxelLimit,
) -> Result<Grid> {
    if direction.iter().chain(&origin).any(|v| !v.is_finite()) {
        return Err(invalid("origin and direction must be finite"));
    }
    Grid::with_limit(
        dims,
        spacing,
        Vec3::from(origin),
        Mat3::from_row_slice(&direction),
        limit,
    )
    .map_err(|e| {
        if is_voxel_quota(&e) {
            SessionError::Quota(Quota::Voxels, e.to_string())
        } else {
            invalid(format!("label-map geometry: {e}"))
        }
    })
}

/// Whether a geometry error of an upload is the voxel quota (too large) rather than bad input.
fn is_voxel_quota(e: &resecta_geom::GeomError) -> bool {
    use resecta_geom::GeomError as G;
    match e {
        G::TooManyVoxels { .. } => true,
        G::EmptyDims(_)
        | G::BadSpacing(_)
        | G::BadOrigin(_)
        | G::SingularDirection
        | G::DataLength { .. }
        | G::VertexIndexOutOfRange { .. }
        | G::TooManyVertices
        | G::NonFiniteVertex(_)
        | G::AttributeLength { .. }
        | G::LabelInTwoRoles { .. }
        | G::BackgroundLabel
        | G::EmptyRole(_)
        | G::NonOrthogonalGrid
        | G::TooFewPoints { .. }
        | G::InvalidParameter { .. }
        | G::TooManyTriangles { .. }
        | G::NotClosed { .. }
        | G::EmptyMesh => false,
    }
}

fn from_raw(raw: &RawLabelMap, limit: VoxelLimit) -> Result<LabelMap> {
    let g = grid(raw.dims, raw.spacing, raw.origin, raw.direction, limit)?;
    let n = raw.dims.iter().product::<usize>();
    let size = raw.data_type.size();
    if n.checked_mul(size) != Some(raw.data.len()) {
        return Err(invalid(format!(
            "label-map data holds {} bytes, but {}×{}×{} voxels of {:?} need {}",
            raw.data.len(),
            raw.dims[0],
            raw.dims[1],
            raw.dims[2],
            raw.data_type,
            n.saturating_mul(size)
        )));
    }
    let bad = |v: i64| invalid(format!("label {v} is outside 0..=65535"));
    let labels: Vec<u16> = match raw.data_type {
        DataType::U8 => raw.data.par_iter().map(|&b| u16::from(b)).collect(),
        DataType::U16 => raw
            .data
            .par_chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect(),
        DataType::I16 => raw
            .data
            .chunks_exact(2)
            .map(|c| {
                let v = i16::from_le_bytes([c[0], c[1]]);
                u16::try_from(v).map_err(|_| bad(v.into()))
            })
            .collect::<Result<_>>()?,
        DataType::U32 => raw
            .data
            .chunks_exact(4)
            .map(|c| {
                let v = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                u16::try_from(v).map_err(|_| bad(v.into()))
            })
            .collect::<Result<_>>()?,
        DataType::I32 => raw
            .data
            .chunks_exact(4)
            .map(|c| {
                let v = i32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                u16::try_from(v).map_err(|_| bad(v.into()))
            })
            .collect::<Result<_>>()?,
    };
    Volume::from_vec(g, labels).map_err(|e| invalid(format!("label map: {e}")))
}

fn sniff(bytes: &[u8]) -> Result<FileFormat> {
    let head = &bytes[..bytes.len().min(4096)];
    let text = String::from_utf8_lossy(head);
    if bytes.starts_with(&[0x1f, 0x8b]) || (bytes.len() >= 348 && &bytes[344..348] == b"n+1\0") {
        Ok(FileFormat::Nifti)
    } else if bytes.starts_with(b"NRRD") {
        Ok(if text.contains("Segment0_") {
            FileFormat::SegNrrd
        } else {
            FileFormat::Nrrd
        })
    } else if text.contains("ObjectType") || text.contains("NDims") {
        Ok(FileFormat::MetaImage)
    } else {
        Err(invalid(
            "the uploaded file is not NIfTI-1, NRRD, .seg.nrrd or MetaImage (.mha)",
        ))
    }
}

fn from_file(format: FileFormat, bytes: &[u8], limit: VoxelLimit) -> Result<LabelMap> {
    let format = match format {
        FileFormat::Auto => sniff(bytes)?,
        f
        @ (FileFormat::Nifti | FileFormat::Nrrd | FileFormat::SegNrrd | FileFormat::MetaImage) => f,
    };
    let io = |e: resecta_io::IoError| {
        use resecta_io::ErrorKind as K;
        match &e.kind {
            K::Geometry(g) if is_voxel_quota(g) => {
                SessionError::Quota(Quota::Voxels, e.to_string())
            }
            K::Io(_)
            | K::UnknownFormat(..)
            | K::BadMagic(_)
            | K::Decompress(_)
            | K::Header(_)
            | K::DataSize { .. }
            | K::Unsupported { .. }
            | K::UnknownValue { .. }
            | K::MissingField(_)
            | K::UnsafePath(_)
            | K::NotLabels(_)
            | K::Segmentation(_)
            | K::Mesh(_)
            | K::Geometry(_) => invalid(e.to_string()),
        }
    };
    let image = match format {
        FileFormat::Nifti => nifti::read_nifti_bytes(bytes, UPLOAD, limit).map_err(io)?,
        FileFormat::Nrrd => nrrd::read_nrrd_bytes(bytes, UPLOAD, limit).map_err(io)?,
        FileFormat::MetaImage => {
            metaimage::read_metaimage_bytes(bytes, UPLOAD, limit).map_err(io)?
        }
        FileFormat::SegNrrd => {
            let seg = nrrd::read_seg_nrrd_bytes(bytes, UPLOAD, limit).map_err(io)?;
            return seg
                .to_label_map()
                .map_err(|k| invalid(format!("{UPLOAD}: {k}")));
        }
        FileFormat::Auto => return Err(invalid("file format could not be told")),
    };
    image
        .to_label_map()
        .map_err(|k| invalid(format!("{UPLOAD}: {k}")))
}

/// Checks the role map against the labels present: some parenchyma label must occur.
pub fn check_roles(roles: &RoleMap, counts: &std::collections::BTreeMap<u16, u64>) -> Result<()> {
    if !roles
        .labels(Role::Parenchyma)
        .iter()
        .any(|l| counts.contains_key(l))
    {
        return Err(invalid(
            "no parenchyma label of the role map occurs in the label map",
        ));
    }
    if !roles
        .labels(Role::Tumor)
        .iter()
        .any(|l| counts.contains_key(l))
    {
        return Err(invalid(
            "no tumour label of the role map occurs in the label map",
        ));
    }
    Ok(())
}

/// Voxels per label (as [`resecta_geom::Volume::value_counts`]), counted in parallel.
fn value_counts(labels: &LabelMap) -> std::collections::BTreeMap<u16, u64> {
    const LABELS: usize = u16::MAX as usize + 1;
    let histogram = labels
        .data()
        .par_chunks(1 << 20)
        .map(|chunk| {
            let mut h = vec![0u64; LABELS];
            for &v in chunk {
                h[usize::from(v)] += 1;
            }
            h
        })
        .reduce(
            || vec![0u64; LABELS],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                a
            },
        );
    histogram
        .into_iter()
        .enumerate()
        .filter(|&(_, n)| n > 0)
        .map(|(l, n)| (l as u16, n))
        .collect()
}

/// Summary of a label map (voxel counts, functional liver volume).
pub fn summary(labels: &LabelMap, roles: &RoleMap) -> LabelMapSummary {
    let g = labels.grid();
    let mut counts = value_counts(labels);
    counts.remove(&0);
    let voxel_ml = g.voxel_volume_mm3() / 1000.0;
    let liver: u64 = counts
        .iter()
        .filter(|(l, _)| roles.role_of(**l).is_some_and(Role::is_functional_liver))
        .map(|(_, c)| c)
        .sum();
    let d = g.direction();
    LabelMapSummary {
        dims: g.dims(),
        spacing: g.spacing(),
        origin: g.origin().into(),
        direction: std::array::from_fn(|k| d[(k / 3, k % 3)]),
        labels: counts,
        liver_ml: liver as Real * voxel_ml,
        roles: roles.clone(),
    }
}

/// Stored header of a label-map blob.
#[derive(Debug, Serialize, Deserialize)]
pub struct StoredHeader {
    pub dims: [usize; 3],
    pub spacing: [Real; 3],
    pub origin: [Real; 3],
    pub direction: [Real; 9],
    pub roles: RoleMap,
}

/// The blob form of a label map and its roles.
pub fn to_blob(labels: &LabelMap, roles: &RoleMap) -> Result<resecta_store::Blob> {
    let s = summary(labels, roles);
    let header = StoredHeader {
        dims: s.dims,
        spacing: s.spacing,
        origin: s.origin,
        direction: s.direction,
        roles: roles.clone(),
    };
    let meta_json =
        serde_json::to_string(&header).map_err(|e| SessionError::Internal(e.to_string()))?;
    let data = labels
        .data()
        .par_iter()
        .flat_map_iter(|v| v.to_le_bytes())
        .collect();
    Ok(resecta_store::Blob { meta_json, data })
}

/// The label map and roles of a stored blob.
pub fn from_blob(blob: &resecta_store::Blob, max_voxels: u64) -> Result<(LabelMap, RoleMap)> {
    let h: StoredHeader = serde_json::from_str(&blob.meta_json)
        .map_err(|e| SessionError::Internal(format!("stored label-map header: {e}")))?;
    let g = grid(
        h.dims,
        h.spacing,
        h.origin,
        h.direction,
        VoxelLimit(max_voxels),
    )?;
    if g.len().checked_mul(2) != Some(blob.data.len()) {
        return Err(SessionError::Internal(format!(
            "stored label map holds {} bytes for {} voxels",
            blob.data.len(),
            g.len()
        )));
    }
    let labels = blob
        .data
        .par_chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    let labels = Volume::from_vec(g, labels).map_err(|e| invalid(format!("label map: {e}")))?;
    Ok((labels, h.roles))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(dims: [usize; 3], spacing: [Real; 3], origin: [Real; 3]) -> LabelMapSource {
        LabelMapSource::Raw(RawLabelMap {
            dims,
            spacing,
            origin,
            direction: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            data_type: DataType::U8,
            data: vec![1; dims.iter().product()],
        })
    }

    fn refusal(source: &LabelMapSource) -> String {
        match decode(source, 1 << 30) {
            Err(SessionError::BadLabelMap(m)) => m,
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    #[test]
    fn geometry_outside_physical_bounds_is_refused_by_field_and_axis() {
        assert!(
            decode(
                &raw([4, 4, 4], [0.8, 0.8, 2.5], [-200.0, 10.0, 0.0]),
                1 << 30
            )
            .is_ok()
        );
        let m = refusal(&raw([4, 4, 4], [0.8, 1e150, 2.5], [0.0; 3]));
        assert!(m.contains("spacing") && m.contains("axis 1"), "{m}");
        let m = refusal(&raw([4, 4, 4], [0.8, 0.8, 1e-5], [0.0; 3]));
        assert!(m.contains("spacing") && m.contains("axis 2"), "{m}");
        // 1 001 voxels of 5 mm: 5 005 mm, just over the 5 m bound.
        let m = refusal(&raw([1001, 1, 1], [5.0, 1.0, 1.0], [0.0; 3]));
        assert!(m.contains("extent") && m.contains("axis 0"), "{m}");
        let m = refusal(&raw([4, 4, 4], [1.0; 3], [0.0, 0.0, 2e5]));
        assert!(m.contains("origin") && m.contains("axis 2"), "{m}");
    }

    #[test]
    fn the_bounds_themselves_are_accepted() {
        let lo = *SPACING_MM.start();
        let hi = *SPACING_MM.end();
        assert!(decode(&raw([2, 2, 2], [lo, hi, 1.0], [MAX_ORIGIN_MM; 3]), 1 << 30).is_ok());
        // 50 voxels of 100 mm: exactly the 5 m bound.
        assert!(decode(&raw([50, 1, 1], [hi, 1.0, 1.0], [0.0; 3]), 1 << 30).is_ok());
    }
}
