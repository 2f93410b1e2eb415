//! NIfTI-1 single files (`.nii`, `.nii.gz`), big- or little-endian.
//!
//! The 348-byte header is parsed by the `nifti` crate; everything it does not check is validated
//! here before any voxel is allocated, and the affine is computed here (the crate's panics on
//! bad quaternions). NIfTI world space is already RAS: sform when `sform_code > 0`, else the
//! qform (quaternion, `qfac` = sign of `pixdim[0]`, spacing from `pixdim`), else
//! `diag(pixdim)`. `scl_slope`/`scl_inter` (slope finite and non-zero, not 1/0) turn the data
//! into floats (`f64` for 32/64-bit sources, `f32` otherwise).
//!
//! The writer writes little-endian `n+1` files with the exact affine as sform and its
//! orthogonal part (polar decomposition) as qform, both with code 1 (scanner); the affine is
//! stored in `f32`, as the format demands.

use std::io::Read;
use std::path::Path;

use flate2::Compression;
use flate2::read::MultiGzDecoder;
use flate2::write::GzEncoder;
use nifti::NiftiHeader;
use resecta_geom::{Grid, Mat3, Mat4, Vec3, VoxelLimit};

use crate::error::{ErrorKind, IoError};
use crate::image::{Image, ScalarType, VoxelData};
use crate::volume_io::{checked_bytes, checked_voxels, is_gzip, read_file, write_file};

const HEADER_SIZE: usize = 348;

/// Reads a `.nii` or `.nii.gz` file (gzip is recognised by content).
pub fn read_nifti(path: impl AsRef<Path>, limit: VoxelLimit) -> Result<Image, IoError> {
    let path = path.as_ref();
    let bytes = read_file(path)?;
    read_nifti_bytes(&bytes, path, limit)
}

/// Reads a NIfTI-1 image from memory; `name` is used in errors.
pub fn read_nifti_bytes(
    bytes: &[u8],
    name: impl AsRef<Path>,
    limit: VoxelLimit,
) -> Result<Image, IoError> {
    read(bytes, limit).map_err(|k| IoError::new(name, k))
}

/// Writes `image` as NIfTI-1, gzipped when the name ends in `.gz`.
pub fn write_nifti(path: impl AsRef<Path>, image: &Image) -> Result<(), IoError> {
    let path = path.as_ref();
    let gz = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("gz"));
    let bytes = nifti_bytes(image, gz).map_err(|k| IoError::new(path, k))?;
    write_file(path, &bytes)
}

fn read(bytes: &[u8], limit: VoxelLimit) -> Result<Image, ErrorKind> {
    let gz = is_gzip(bytes);
    let mut stream: Box<dyn Read + '_> = if gz {
        Box::new(MultiGzDecoder::new(bytes))
    } else {
        Box::new(bytes)
    };
    let stream_err = |e: std::io::Error| {
        if gz {
            ErrorKind::Decompress(e.to_string())
        } else {
            ErrorKind::Io(e)
        }
    };

    let mut raw = [0u8; HEADER_SIZE];
    let got = read_up_to(&mut stream, &mut raw).map_err(stream_err)?;
    if got < HEADER_SIZE {
        return Err(ErrorKind::DataSize {
            expected: HEADER_SIZE as u64,
            got: got as u64,
        });
    }
    let sizeof_hdr = [
        i32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]),
        i32::from_be_bytes([raw[0], raw[1], raw[2], raw[3]]),
    ];
    if sizeof_hdr.contains(&540) {
        return Err(ErrorKind::Unsupported {
            what: "format",
            value: "NIfTI-2".into(),
        });
    }
    if !sizeof_hdr.contains(&(HEADER_SIZE as i32)) {
        return Err(ErrorKind::BadMagic("NIfTI-1 (sizeof_hdr is not 348)"));
    }
    match &raw[344..348] {
        b"n+1\0" => {}
        b"ni1\0" => {
            return Err(ErrorKind::Unsupported {
                what: "NIfTI layout",
                value: "separate .hdr/.img pair".into(),
            });
        }
        _ => return Err(ErrorKind::BadMagic("NIfTI-1 (magic is not \"n+1\")")),
    }
    let h = NiftiHeader::from_reader(&raw[..]).map_err(|e| ErrorKind::Header(e.to_string()))?;
    if h.sizeof_hdr != HEADER_SIZE as i32 {
        return Err(ErrorKind::Header("inconsistent byte order".into()));
    }

    let dims = dims_of(&h)?;
    let ty = scalar_type(h.datatype)?;
    let pixdim = pixdim_of(&h)?;
    let n = checked_voxels(&dims, limit)?;
    let nbytes = checked_bytes(n, ty.size())?;
    if !h.vox_offset.is_finite() || h.vox_offset.fract() != 0.0 {
        return Err(ErrorKind::Header(format!("vox_offset {}", h.vox_offset)));
    }
    // Some writers leave 0 in single files; the data then starts right after the extender.
    let vox_offset = if h.vox_offset == 0.0 {
        352
    } else if h.vox_offset < 352.0 {
        return Err(ErrorKind::Header(format!(
            "vox_offset {} is inside the 352-byte header",
            h.vox_offset
        )));
    } else {
        h.vox_offset as u64
    };
    let affine = affine_of(&h, pixdim)?;
    let grid = Grid::from_affine(dims, &affine, limit)?;

    // Read exactly what the header promises, growing with the actual input only.
    let need = (vox_offset - HEADER_SIZE as u64)
        .checked_add(nbytes)
        .ok_or_else(|| ErrorKind::Header(format!("vox_offset {} is too large", h.vox_offset)))?;
    let mut rest = Vec::new();
    (&mut stream)
        .take(need)
        .read_to_end(&mut rest)
        .map_err(stream_err)?;
    if (rest.len() as u64) < need {
        return Err(ErrorKind::DataSize {
            expected: need.saturating_add(HEADER_SIZE as u64),
            got: (HEADER_SIZE + rest.len()) as u64,
        });
    }
    if gz {
        // Reaching the end of the stream checks the gzip trailer (CRC and length).
        let mut sink = [0u8; 4096];
        while stream.read(&mut sink).map_err(stream_err)? > 0 {}
    }
    let start = (vox_offset - HEADER_SIZE as u64) as usize;
    let big_endian = h.endianness == nifti::Endianness::Big;
    let data = VoxelData::from_bytes(&rest[start..], ty, big_endian);
    let data = scale(data, h.scl_slope, h.scl_inter);
    Ok(Image::new(grid, data)?)
}

/// Reads until `buf` is full or the stream ends; returns how many bytes were read.
fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..])? {
            0 => break,
            k => got += k,
        }
    }
    Ok(got)
}

/// The three spatial sizes; a fourth or higher axis must have size 1.
fn dims_of(h: &NiftiHeader) -> Result<[usize; 3], ErrorKind> {
    let nd = usize::from(h.dim[0]);
    if !(1..=7).contains(&nd) {
        return Err(ErrorKind::Header(format!("dim[0] = {nd}, not 1..=7")));
    }
    let mut dims = [1usize; 3];
    for (k, &d) in h.dim[1..=nd].iter().enumerate() {
        // dim is signed 16-bit in the format.
        if d == 0 || d > i16::MAX as u16 {
            return Err(ErrorKind::Header(format!(
                "dim[{}] = {} is not a positive size",
                k + 1,
                d as i16
            )));
        }
        if k < 3 {
            dims[k] = usize::from(d);
        } else if d != 1 {
            return Err(ErrorKind::Unsupported {
                what: "NIfTI dimensionality",
                value: format!("{nd}D image with dim = {:?}", &h.dim[1..=nd]),
            });
        }
    }
    Ok(dims)
}

/// `pixdim[1..=3]`; axes that exist must have positive finite spacing, missing ones default to 1.
fn pixdim_of(h: &NiftiHeader) -> Result<[f64; 3], ErrorKind> {
    let nd = usize::from(h.dim[0]).min(3);
    let mut p = [1.0; 3];
    for (k, pk) in p.iter_mut().enumerate() {
        let v = f64::from(h.pixdim[k + 1]);
        if k < nd {
            if !v.is_finite() || v <= 0.0 {
                return Err(ErrorKind::Geometry(resecta_geom::GeomError::BadSpacing([
                    f64::from(h.pixdim[1]),
                    f64::from(h.pixdim[2]),
                    f64::from(h.pixdim[3]),
                ])));
            }
            *pk = v;
        } else if v.is_finite() && v > 0.0 {
            *pk = v;
        }
    }
    Ok(p)
}

fn scalar_type(code: i16) -> Result<ScalarType, ErrorKind> {
    Ok(match code {
        2 => ScalarType::U8,
        4 => ScalarType::I16,
        8 => ScalarType::I32,
        16 => ScalarType::F32,
        64 => ScalarType::F64,
        256 => ScalarType::I8,
        512 => ScalarType::U16,
        768 => ScalarType::U32,
        _ => {
            let name = match code {
                1 => "binary",
                32 => "complex64",
                128 => "rgb24",
                1024 => "int64",
                1280 => "uint64",
                1536 => "float128",
                1792 => "complex128",
                2048 => "complex256",
                2304 => "rgba32",
                _ => "unknown",
            };
            return Err(ErrorKind::Unsupported {
                what: "NIfTI datatype",
                value: format!("{code} ({name})"),
            });
        }
    })
}

fn nifti_code(ty: ScalarType) -> i16 {
    match ty {
        ScalarType::U8 => 2,
        ScalarType::I16 => 4,
        ScalarType::I32 => 8,
        ScalarType::F32 => 16,
        ScalarType::F64 => 64,
        ScalarType::I8 => 256,
        ScalarType::U16 => 512,
        ScalarType::U32 => 768,
    }
}

/// Index→RAS affine: sform, else qform, else `diag(pixdim)`.
fn affine_of(h: &NiftiHeader, pixdim: [f64; 3]) -> Result<Mat4, ErrorKind> {
    let mut m = Mat4::identity();
    if h.sform_code > 0 {
        for (r, row) in [h.srow_x, h.srow_y, h.srow_z].iter().enumerate() {
            for (c, &v) in row.iter().enumerate() {
                if !v.is_finite() {
                    return Err(ErrorKind::Header(format!("non-finite sform entry {v}")));
                }
                m[(r, c)] = f64::from(v);
            }
        }
    } else if h.qform_code > 0 {
        let q = [h.quatern_b, h.quatern_c, h.quatern_d];
        let t = [h.quatern_x, h.quatern_y, h.quatern_z];
        if q.iter().chain(&t).any(|v| !v.is_finite()) {
            return Err(ErrorKind::Header("non-finite qform parameters".into()));
        }
        let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let r = quaternion_to_rotation(q.map(f64::from));
        let lin = r * Mat3::from_diagonal(&Vec3::new(pixdim[0], pixdim[1], qfac * pixdim[2]));
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&lin);
        m.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&Vec3::new(t[0].into(), t[1].into(), t[2].into()));
    } else {
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Mat3::from_diagonal(&Vec3::from(pixdim)));
    }
    Ok(m)
}

/// Rotation of the unit quaternion `(a, b, c, d)` with `a` implied, as in `nifti1_io.c`.
fn quaternion_to_rotation([b, c, d]: [f64; 3]) -> Mat3 {
    let s = b * b + c * c + d * d;
    let (a, b, c, d) = if 1.0 - s < 1e-7 {
        // Not a unit quaternion with a ≥ 0: renormalise (b, c, d), a 180° rotation.
        let n = s.sqrt().max(f64::MIN_POSITIVE);
        (0.0, b / n, c / n, d / n)
    } else {
        ((1.0 - s).sqrt(), b, c, d)
    };
    Mat3::new(
        a * a + b * b - c * c - d * d,
        2.0 * (b * c - a * d),
        2.0 * (b * d + a * c),
        2.0 * (b * c + a * d),
        a * a + c * c - b * b - d * d,
        2.0 * (c * d - a * b),
        2.0 * (b * d - a * c),
        2.0 * (c * d + a * b),
        a * a + d * d - c * c - b * b,
    )
}

/// `(b, c, d, qfac)` of the nearest rotation to `dir` (polar decomposition), as in
/// `nifti1_io.c`'s `mat44_to_quatern`.
fn rotation_to_quaternion(dir: &Mat3) -> Result<([f64; 3], f64), ErrorKind> {
    let svd = dir.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(ErrorKind::Header(
            "direction has no polar decomposition".into(),
        ));
    };
    let mut r = u * vt;
    let qfac = if r.determinant() < 0.0 {
        r.set_column(2, &(-r.column(2)));
        -1.0
    } else {
        1.0
    };
    let e = |i: usize, j: usize| r[(i - 1, j - 1)];
    let t = e(1, 1) + e(2, 2) + e(3, 3) + 1.0;
    let (a, mut b, mut c, mut d);
    if t > 0.5 {
        a = 0.5 * t.sqrt();
        b = 0.25 * (e(3, 2) - e(2, 3)) / a;
        c = 0.25 * (e(1, 3) - e(3, 1)) / a;
        d = 0.25 * (e(2, 1) - e(1, 2)) / a;
    } else {
        let xd = 1.0 + e(1, 1) - (e(2, 2) + e(3, 3));
        let yd = 1.0 + e(2, 2) - (e(1, 1) + e(3, 3));
        let zd = 1.0 + e(3, 3) - (e(1, 1) + e(2, 2));
        if xd > 1.0 {
            b = 0.5 * xd.sqrt();
            c = 0.25 * (e(1, 2) + e(2, 1)) / b;
            d = 0.25 * (e(1, 3) + e(3, 1)) / b;
            a = 0.25 * (e(3, 2) - e(2, 3)) / b;
        } else if yd > 1.0 {
            c = 0.5 * yd.sqrt();
            b = 0.25 * (e(1, 2) + e(2, 1)) / c;
            d = 0.25 * (e(2, 3) + e(3, 2)) / c;
            a = 0.25 * (e(1, 3) - e(3, 1)) / c;
        } else {
            d = 0.5 * zd.sqrt();
            b = 0.25 * (e(1, 3) + e(3, 1)) / d;
            c = 0.25 * (e(2, 3) + e(3, 2)) / d;
            a = 0.25 * (e(2, 1) - e(1, 2)) / d;
        }
        if a < 0.0 {
            (b, c, d) = (-b, -c, -d);
        }
    }
    Ok(([b, c, d], qfac))
}

/// Applies `scl_slope`/`scl_inter` when they are not the identity.
fn scale(data: VoxelData, slope: f32, inter: f32) -> VoxelData {
    if !slope.is_finite() || slope == 0.0 {
        return data;
    }
    let inter = if inter.is_finite() { inter } else { 0.0 };
    if slope == 1.0 && inter == 0.0 {
        return data;
    }
    let (s, i) = (f64::from(slope), f64::from(inter));
    match data.scalar_type() {
        ScalarType::I32 | ScalarType::U32 | ScalarType::F64 => {
            VoxelData::F64(data.to_f64().into_iter().map(|v| v * s + i).collect())
        }
        ScalarType::U8 | ScalarType::I8 | ScalarType::U16 | ScalarType::I16 | ScalarType::F32 => {
            VoxelData::F32(
                data.to_f64()
                    .into_iter()
                    .map(|v| (v * s + i) as f32)
                    .collect(),
            )
        }
    }
}

/// The bytes of a little-endian NIfTI-1 file of `image`, gzipped if asked.
pub fn nifti_bytes(image: &Image, gz: bool) -> Result<Vec<u8>, ErrorKind> {
    let grid = image.grid();
    let dims = grid.dims();
    if dims.iter().any(|&d| d > i16::MAX as usize) {
        return Err(ErrorKind::Unsupported {
            what: "NIfTI-1 size",
            value: format!("{dims:?} (each must be at most 32767)"),
        });
    }
    let ty = image.data().scalar_type();
    let spacing = grid.spacing();
    let origin = grid.origin();
    let affine = grid.affine();
    let ([qb, qc, qd], qfac) = rotation_to_quaternion(&grid.direction())?;

    let mut h = vec![0u8; 352];
    let mut put = |off: usize, b: &[u8]| h[off..off + b.len()].copy_from_slice(b);
    put(0, &(HEADER_SIZE as i32).to_le_bytes());
    put(38, b"r"); // regular
    let dim = [3, dims[0], dims[1], dims[2], 1, 1, 1, 1];
    for (k, d) in dim.iter().enumerate() {
        put(40 + 2 * k, &(*d as i16).to_le_bytes());
    }
    put(70, &nifti_code(ty).to_le_bytes());
    put(72, &((ty.size() * 8) as i16).to_le_bytes());
    let pixdim = [qfac, spacing[0], spacing[1], spacing[2], 1.0, 1.0, 1.0, 1.0];
    for (k, p) in pixdim.iter().enumerate() {
        put(76 + 4 * k, &(*p as f32).to_le_bytes());
    }
    put(108, &352f32.to_le_bytes()); // vox_offset
    put(112, &1f32.to_le_bytes()); // scl_slope
    put(123, &[2]); // xyzt_units: mm
    put(148, b"resecta");
    put(252, &1i16.to_le_bytes()); // qform_code: scanner
    put(254, &1i16.to_le_bytes()); // sform_code: scanner
    let quat = [qb, qc, qd, origin[0], origin[1], origin[2]];
    for (k, v) in quat.iter().enumerate() {
        put(256 + 4 * k, &(*v as f32).to_le_bytes());
    }
    for r in 0..3 {
        for c in 0..4 {
            put(280 + 16 * r + 4 * c, &(affine[(r, c)] as f32).to_le_bytes());
        }
    }
    put(344, b"n+1\0");
    // Bytes 348..352: extender, no extensions.

    let data = image.data().to_bytes(false);
    if gz {
        use std::io::Write;
        let mut enc = GzEncoder::new(Vec::new(), Compression::default());
        enc.write_all(&h)?;
        enc.write_all(&data)?;
        Ok(enc.finish()?)
    } else {
        h.extend_from_slice(&data);
        Ok(h)
    }
}
