//! Format dispatch by file name ([`read_image`], [`write_image`]) and the helpers the image
//! readers share: bounded decompression and safe detached-data paths.

use std::borrow::Cow;
use std::io::Read;
use std::path::{Component, Path, PathBuf};

use flate2::read::{MultiGzDecoder, ZlibDecoder};
use resecta_geom::VoxelLimit;
use resecta_geom::grid::LabelMap;

use crate::error::{ErrorKind, IoError};
use crate::image::Image;
use crate::{metaimage, nifti, nrrd};

/// The image formats this crate reads and writes, told apart by file name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageFormat {
    /// `.nii` or (`gz`) `.nii.gz`.
    Nifti { gz: bool },
    /// `.nrrd` (attached data) or (`detached`) `.nhdr`.
    Nrrd { detached: bool },
    /// 3D Slicer segmentation, `.seg.nrrd`.
    SegNrrd,
    /// `.mha` (data in the same file) or (`detached`) `.mhd`.
    MetaImage { detached: bool },
}

const KNOWN: &str = ".nii, .nii.gz, .nrrd, .nhdr, .seg.nrrd, .mha, .mhd";

impl ImageFormat {
    /// The format named by the file's extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Self, IoError> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let format = if name.ends_with(".nii.gz") {
            Self::Nifti { gz: true }
        } else if name.ends_with(".nii") {
            Self::Nifti { gz: false }
        } else if name.ends_with(".seg.nrrd") {
            Self::SegNrrd
        } else if name.ends_with(".nrrd") {
            Self::Nrrd { detached: false }
        } else if name.ends_with(".nhdr") {
            Self::Nrrd { detached: true }
        } else if name.ends_with(".mha") {
            Self::MetaImage { detached: false }
        } else if name.ends_with(".mhd") {
            Self::MetaImage { detached: true }
        } else {
            return Err(IoError::new(path, ErrorKind::UnknownFormat(name, KNOWN)));
        };
        Ok(format)
    }
}

/// Reads any supported image; a `.seg.nrrd` is flattened to one `u16` label image
/// ([`nrrd::Segmentation::to_label_map`]).
pub fn read_image(path: impl AsRef<Path>, limit: VoxelLimit) -> Result<Image, IoError> {
    let path = path.as_ref();
    match ImageFormat::from_path(path)? {
        ImageFormat::Nifti { .. } => nifti::read_nifti(path, limit),
        ImageFormat::Nrrd { .. } => nrrd::read_nrrd(path, limit),
        ImageFormat::SegNrrd => {
            let seg = nrrd::read_seg_nrrd(path, limit)?;
            let labels = seg.to_label_map().map_err(|e| IoError::new(path, e))?;
            Ok(Image::from_label_map(&labels))
        }
        ImageFormat::MetaImage { .. } => metaimage::read_metaimage(path, limit),
    }
}

/// Writes an image in the format its extension names (NIfTI gzipped for `.nii.gz`; NRRD and
/// MetaImage always compressed). A `.seg.nrrd` needs integral values in `0..=65535`.
pub fn write_image(path: impl AsRef<Path>, image: &Image) -> Result<(), IoError> {
    let path = path.as_ref();
    match ImageFormat::from_path(path)? {
        ImageFormat::Nifti { .. } => nifti::write_nifti(path, image),
        ImageFormat::Nrrd { .. } => nrrd::write_nrrd(path, image),
        ImageFormat::SegNrrd => {
            let labels = image.to_label_map().map_err(|e| IoError::new(path, e))?;
            nrrd::write_seg_nrrd(path, &nrrd::Segmentation::from_label_map(labels))
        }
        ImageFormat::MetaImage { .. } => metaimage::write_metaimage(path, image, true),
    }
}

/// Reads any supported image as a label map (values must be integers in `0..=65535`).
pub fn read_label_map(path: impl AsRef<Path>, limit: VoxelLimit) -> Result<LabelMap, IoError> {
    let path = path.as_ref();
    read_image(path, limit)?
        .to_label_map()
        .map_err(|e| IoError::new(path, e))
}

/// Writes a label map as `u16` in the format its extension names.
pub fn write_label_map(path: impl AsRef<Path>, labels: &LabelMap) -> Result<(), IoError> {
    write_image(path, &Image::from_label_map(labels))
}

/// Reads a whole file, naming it in the error.
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>, IoError> {
    std::fs::read(path).map_err(|e| IoError::new(path, e))
}

/// Writes a whole file, naming it in the error.
pub(crate) fn write_file(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    std::fs::write(path, bytes).map_err(|e| IoError::new(path, e))
}

/// Reads a detached data file. The error (reported against the header) says that the file
/// named by `key` failed, not its name: the name is header text, often a patient's name.
pub(crate) fn read_data_file(path: &Path, key: &'static str) -> Result<Vec<u8>, ErrorKind> {
    std::fs::read(path).map_err(|e| {
        ErrorKind::Io(std::io::Error::new(
            e.kind(),
            format!("the data file named by the header's `{key}`: {e}"),
        ))
    })
}

/// Which compressed stream to inflate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Codec {
    Gzip,
    Zlib,
}

/// Inflates at most `cap + 1` bytes, so callers can tell "longer than expected" without
/// ever holding more; memory grows with the actual output, never with a header's claim.
pub(crate) fn inflate(data: &[u8], codec: Codec, cap: u64) -> Result<Vec<u8>, ErrorKind> {
    let mut out = Vec::new();
    let result = match codec {
        Codec::Gzip => MultiGzDecoder::new(data)
            .take(cap.saturating_add(1))
            .read_to_end(&mut out),
        Codec::Zlib => ZlibDecoder::new(data)
            .take(cap.saturating_add(1))
            .read_to_end(&mut out),
    };
    result.map_err(|e| ErrorKind::Decompress(e.to_string()))?;
    Ok(out)
}

/// Whether `data` starts with the gzip magic.
pub(crate) fn is_gzip(data: &[u8]) -> bool {
    data.starts_with(&[0x1f, 0x8b])
}

/// The detached data file `name` (the value of the header's `key`), relative to the header's
/// folder; absolute paths and `..` are refused so a header cannot reach outside its folder.
pub(crate) fn data_file_path(
    header: &Path,
    name: &str,
    key: &'static str,
) -> Result<PathBuf, ErrorKind> {
    let rel = Path::new(name);
    let safe = !name.is_empty()
        && rel
            .components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    if !safe {
        return Err(ErrorKind::UnsafePath(key));
    }
    Ok(header.parent().unwrap_or(Path::new("")).join(rel))
}

/// Voxel count of `dims` under `limit` (any number of axes), refusing zero and overflow.
pub(crate) fn checked_voxels(dims: &[usize], limit: VoxelLimit) -> Result<usize, ErrorKind> {
    let mut d3 = [1usize; 3];
    // Fold extra leading axes into the first so the geometry kernel's check applies.
    let split = dims.len().saturating_sub(3);
    for (k, &d) in dims.iter().enumerate() {
        let slot = k.saturating_sub(split);
        d3[slot] = match d3[slot].checked_mul(d) {
            Some(v) => v,
            None => usize::MAX,
        };
    }
    if dims.contains(&0) {
        return Err(ErrorKind::Header(format!(
            "zero size in dimensions {dims:?}"
        )));
    }
    Ok(limit.check(d3)?)
}

/// `voxels * size` bytes, refusing overflow.
pub(crate) fn checked_bytes(voxels: usize, size: usize) -> Result<u64, ErrorKind> {
    (voxels as u64)
        .checked_mul(size as u64)
        .ok_or_else(|| ErrorKind::Header("data size overflows".into()))
}

/// Lines of a text header from byte `start`: each line without its `\n` (and a trailing `\r`),
/// with the offset just after it (where attached data would begin).
pub(crate) fn header_lines(
    bytes: &[u8],
    start: usize,
) -> impl Iterator<Item = (Cow<'_, str>, usize)> {
    let mut pos = start.min(bytes.len());
    std::iter::from_fn(move || {
        if pos >= bytes.len() {
            return None;
        }
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |e| pos + e);
        let raw = bytes[pos..end]
            .strip_suffix(b"\r")
            .unwrap_or(&bytes[pos..end]);
        pos = (end + 1).min(bytes.len());
        Some((String::from_utf8_lossy(raw), pos))
    })
}
