//! MetaImage: `.mha` (data `LOCAL`, after the header) and `.mhd` + `ElementDataFile`
//! (`.raw`, or zlib `.zraw` with `CompressedData = True`).
//!
//! As in ITK, the world frame of a MetaImage is LPS whatever `AnatomicalOrientation` says (that
//! key only describes the axes and is ignored); `TransformMatrix` (or `Rotation`/`Orientation`)
//! lists the world direction of axis 0, then axis 1, then axis 2 (ITK's
//! `SetDirection(i, tm[3i..3i+3])`), `Offset` (or `Position`/`Origin`) is the centre of voxel 0.
//! Both are converted to RAS by negating x and y.

use std::io::Write;
use std::path::Path;

use flate2::Compression;
use flate2::write::ZlibEncoder;
use resecta_geom::{GeomError, Grid, Mat3, Vec3, VoxelLimit};

use crate::error::{ErrorKind, IoError};
use crate::image::{Image, ScalarType, VoxelData};
use crate::volume_io::{
    Codec, checked_bytes, checked_voxels, data_file_path, header_lines, inflate, read_data_file,
    read_file, write_file,
};

/// Reads a `.mha` or `.mhd` (with its data file).
pub fn read_metaimage(path: impl AsRef<Path>, limit: VoxelLimit) -> Result<Image, IoError> {
    let path = path.as_ref();
    let bytes = read_file(path)?;
    parse(&bytes, Some(path), limit).map_err(|k| IoError::new(path, k))
}

/// Reads a MetaImage with `ElementDataFile = LOCAL` from memory; `name` is used in errors.
pub fn read_metaimage_bytes(
    bytes: &[u8],
    name: impl AsRef<Path>,
    limit: VoxelLimit,
) -> Result<Image, IoError> {
    parse(bytes, None, limit).map_err(|k| IoError::new(name, k))
}

/// Writes `.mha` (data inside) or `.mhd` (data beside it as `<stem>.zraw` or `<stem>.raw`),
/// zlib-compressed when `compress`.
pub fn write_metaimage(
    path: impl AsRef<Path>,
    image: &Image,
    compress: bool,
) -> Result<(), IoError> {
    let path = path.as_ref();
    let err = |k| IoError::new(path, k);
    let detached = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mhd"));
    let data = payload(image, compress).map_err(err)?;
    if detached {
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let name = format!("{stem}.{}", if compress { "zraw" } else { "raw" });
        write_file(&path.with_file_name(&name), &data)?;
        write_file(path, header(image, compress, data.len(), &name).as_bytes())
    } else {
        let mut out = header(image, compress, data.len(), "LOCAL").into_bytes();
        out.extend_from_slice(&data);
        write_file(path, &out)
    }
}

/// The bytes of a `.mha` of `image`.
pub fn mha_bytes(image: &Image, compress: bool) -> Result<Vec<u8>, ErrorKind> {
    let data = payload(image, compress)?;
    let mut out = header(image, compress, data.len(), "LOCAL").into_bytes();
    out.extend_from_slice(&data);
    Ok(out)
}

fn payload(image: &Image, compress: bool) -> Result<Vec<u8>, ErrorKind> {
    let raw = image.data().to_bytes(false);
    if !compress {
        return Ok(raw);
    }
    let mut enc = ZlibEncoder::new(Vec::new(), Compression::default());
    enc.write_all(&raw)?;
    Ok(enc.finish()?)
}

fn header(image: &Image, compress: bool, compressed_size: usize, data_file: &str) -> String {
    let g = image.grid();
    let d = g.direction();
    let lps = |v: Vec3| format!("{} {} {}", -v[0], -v[1], v[2]);
    let tm: Vec<String> = (0..3).map(|c| lps(d.column(c).into_owned())).collect();
    let [sx, sy, sz] = g.spacing();
    let [nx, ny, nz] = g.dims();
    let ty = match image.data().scalar_type() {
        ScalarType::U8 => "MET_UCHAR",
        ScalarType::I8 => "MET_CHAR",
        ScalarType::U16 => "MET_USHORT",
        ScalarType::I16 => "MET_SHORT",
        ScalarType::U32 => "MET_UINT",
        ScalarType::I32 => "MET_INT",
        ScalarType::F32 => "MET_FLOAT",
        ScalarType::F64 => "MET_DOUBLE",
    };
    let mut h = format!(
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n\
         CompressedData = {}\n",
        if compress { "True" } else { "False" }
    );
    if compress {
        h.push_str(&format!("CompressedDataSize = {compressed_size}\n"));
    }
    h.push_str(&format!(
        "TransformMatrix = {}\nOffset = {}\nCenterOfRotation = 0 0 0\n\
         ElementSpacing = {sx} {sy} {sz}\nDimSize = {nx} {ny} {nz}\nElementType = {ty}\n\
         ElementDataFile = {data_file}\n",
        tm.join(" "),
        lps(g.origin())
    ));
    h
}

fn scalar_type(name: &str) -> Result<ScalarType, ErrorKind> {
    Ok(match name.to_ascii_uppercase().as_str() {
        "MET_UCHAR" => ScalarType::U8,
        "MET_CHAR" => ScalarType::I8,
        "MET_USHORT" => ScalarType::U16,
        "MET_SHORT" => ScalarType::I16,
        "MET_UINT" => ScalarType::U32,
        "MET_INT" => ScalarType::I32,
        "MET_FLOAT" => ScalarType::F32,
        "MET_DOUBLE" => ScalarType::F64,
        _ => {
            return Err(ErrorKind::UnknownValue {
                key: "MetaImage ElementType",
                known: "MET_CHAR, MET_UCHAR, MET_SHORT, MET_USHORT, MET_INT, MET_UINT, \
                        MET_FLOAT, MET_DOUBLE",
            });
        }
    })
}

/// `count` finite numbers: the value of `key` (named in the error, the value is not).
fn numbers(key: &str, value: &str, count: usize) -> Result<Vec<f64>, ErrorKind> {
    let v: Option<Vec<f64>> = value
        .split_whitespace()
        .map(|t| t.parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect();
    match v {
        Some(v) if v.len() == count => Ok(v),
        _ => Err(ErrorKind::Header(format!(
            "{key}: expected {count} finite numbers"
        ))),
    }
}

fn boolean(key: &str, value: &str) -> Result<bool, ErrorKind> {
    match value.to_ascii_lowercase().as_str() {
        "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        _ => Err(ErrorKind::Header(format!("{key}: expected True or False"))),
    }
}

fn parse(bytes: &[u8], header_path: Option<&Path>, limit: VoxelLimit) -> Result<Image, ErrorKind> {
    // Header lines up to and including ElementDataFile, which must come last.
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut pos = bytes.len();
    let mut data_file = None;
    for (k, (line, next)) in header_lines(bytes, 0).enumerate() {
        pos = next;
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let Some((k, v)) = line.split_once('=') else {
            return Err(if fields.is_empty() {
                ErrorKind::BadMagic("MetaImage")
            } else {
                ErrorKind::Header(format!("line {} is not `Key = Value`", k + 1))
            });
        };
        let (k, v) = (k.trim().to_ascii_lowercase(), v.trim().to_string());
        if fields.is_empty() && !matches!(k.as_str(), "objecttype" | "ndims" | "comment") {
            return Err(ErrorKind::BadMagic("MetaImage"));
        }
        if k == "elementdatafile" {
            data_file = Some(v);
            break;
        }
        fields.push((k, v));
    }
    let field = |k: &str| fields.iter().find(|(f, _)| f == k).map(|(_, v)| v.as_str());
    let first = |ks: &[&'static str]| ks.iter().find_map(|&k| field(k).map(|v| (k, v)));
    let need = |k: &'static str| field(k).ok_or(ErrorKind::MissingField(k));
    let data_file = data_file.ok_or(ErrorKind::MissingField("ElementDataFile"))?;

    if let Some(o) = field("objecttype")
        && !o.eq_ignore_ascii_case("image")
    {
        return Err(ErrorKind::UnknownValue {
            key: "MetaImage ObjectType",
            known: "Image",
        });
    }
    let ndims = need("ndims")?;
    if ndims != "3" {
        return Err(match ndims.parse::<u32>() {
            Ok(n) => ErrorKind::Unsupported {
                what: "MetaImage NDims",
                value: format!("{n} (only 3)"),
            },
            Err(_) => ErrorKind::Header("NDims is not a whole number".into()),
        });
    }
    let dims: Vec<usize> = need("dimsize")?
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| ErrorKind::Header("DimSize: expected 3 whole numbers".into()))?;
    let [nx, ny, nz] = dims[..] else {
        return Err(ErrorKind::Header(format!(
            "DimSize has {} sizes, expected 3",
            dims.len()
        )));
    };
    let ty = scalar_type(need("elementtype")?)?;
    if let Some(c) = field("elementnumberofchannels")
        && c != "1"
    {
        return Err(match c.parse::<u32>() {
            Ok(n) => ErrorKind::Unsupported {
                what: "MetaImage ElementNumberOfChannels",
                value: format!("{n} (only 1)"),
            },
            Err(_) => ErrorKind::Header("ElementNumberOfChannels is not a whole number".into()),
        });
    }
    if let Some(b) = field("binarydata")
        && !boolean("BinaryData", b)?
    {
        return Err(ErrorKind::Unsupported {
            what: "MetaImage data",
            value: "ASCII (BinaryData = False)".into(),
        });
    }
    let big_endian = match first(&["binarydatabyteordermsb", "elementbyteordermsb"]) {
        Some((k, v)) => boolean(k, v)?,
        None => false,
    };
    let compressed = match field("compresseddata") {
        Some(v) => boolean("CompressedData", v)?,
        None => false,
    };

    let spacing = match field("elementspacing") {
        Some(v) => numbers("ElementSpacing", v, 3)?,
        None => vec![1.0; 3],
    };
    let spacing = [spacing[0], spacing[1], spacing[2]];
    if spacing.iter().any(|&s| s <= 0.0) {
        return Err(GeomError::BadSpacing(spacing).into());
    }
    let origin = match first(&["offset", "position", "origin"]) {
        Some((k, v)) => numbers(k, v, 3)?,
        None => vec![0.0; 3],
    };
    let tm = match first(&["transformmatrix", "rotation", "orientation"]) {
        Some((k, v)) => numbers(k, v, 9)?,
        None => vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
    };
    // Column c of the direction is tm[3c..3c+3]; LPS → RAS negates rows x and y.
    let flip = Vec3::new(-1.0, -1.0, 1.0);
    let mut dir = Mat3::zeros();
    for c in 0..3 {
        dir.set_column(
            c,
            &Vec3::new(tm[3 * c], tm[3 * c + 1], tm[3 * c + 2]).component_mul(&flip),
        );
    }
    let origin = Vec3::new(origin[0], origin[1], origin[2]).component_mul(&flip);
    let n = checked_voxels(&[nx, ny, nz], limit)?;
    let nbytes = checked_bytes(n, ty.size())?;
    let grid = Grid::with_limit([nx, ny, nz], spacing, origin, dir, limit)?;

    // Data.
    let file_bytes;
    let payload: &[u8] = if data_file.eq_ignore_ascii_case("local") {
        &bytes[pos..]
    } else {
        if data_file.starts_with("LIST") || data_file.contains('%') || data_file.contains(' ') {
            return Err(ErrorKind::Unsupported {
                what: "MetaImage ElementDataFile",
                value: "a list or pattern of data files".into(),
            });
        }
        let Some(hp) = header_path else {
            return Err(ErrorKind::Unsupported {
                what: "MetaImage ElementDataFile",
                value: "detached data without the header's folder (attach the data: \
                        ElementDataFile = LOCAL, .mha)"
                    .into(),
            });
        };
        const KEY: &str = "ElementDataFile";
        file_bytes = read_data_file(&data_file_path(hp, &data_file, KEY)?, KEY)?;
        &file_bytes
    };
    let short = |got: u64| ErrorKind::DataSize {
        expected: nbytes,
        got,
    };
    let raw;
    let body: &[u8] = if compressed {
        let input = match field("compresseddatasize") {
            Some(s) => {
                let k: u64 = s.parse().map_err(|_| {
                    ErrorKind::Header("CompressedDataSize is not a whole number".into())
                })?;
                if k > payload.len() as u64 {
                    return Err(ErrorKind::DataSize {
                        expected: k,
                        got: payload.len() as u64,
                    });
                }
                &payload[..k as usize]
            }
            None => payload,
        };
        raw = inflate(input, Codec::Zlib, nbytes)?;
        if (raw.len() as u64) < nbytes {
            return Err(short(raw.len() as u64));
        }
        &raw[..nbytes as usize]
    } else {
        let len = payload.len() as u64;
        let skip = match field("headersize") {
            Some("-1") => len.checked_sub(nbytes).ok_or_else(|| short(len))?,
            Some(s) => s
                .parse::<u64>()
                .map_err(|_| ErrorKind::Header("HeaderSize is not a whole number or -1".into()))?,
            None => 0,
        };
        if skip.saturating_add(nbytes) > len {
            return Err(short(len.saturating_sub(skip)));
        }
        &payload[skip as usize..(skip + nbytes) as usize]
    };
    Ok(Image::new(
        grid,
        VoxelData::from_bytes(body, ty, big_endian),
    )?)
}
