//! Typed images read from files: a [`Grid`] (index→RAS mm, `i` fastest) and voxel values in the
//! file's own scalar type, with conversions to the engine's label maps and float volumes.

use resecta_geom::grid::LabelMap;
use resecta_geom::{GeomError, Grid, Volume};

use crate::error::ErrorKind;

/// The scalar type of stored voxels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ScalarType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    F32,
    F64,
}

impl ScalarType {
    /// Bytes per value.
    pub fn size(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::U32 | Self::I32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// Whether values are integers.
    pub fn is_integral(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }
}

/// Voxel values in `i`-fastest order, in their stored scalar type.
#[derive(Debug, Clone, PartialEq)]
pub enum VoxelData {
    U8(Vec<u8>),
    I8(Vec<i8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    U32(Vec<u32>),
    I32(Vec<i32>),
    F32(Vec<f32>),
    F64(Vec<f64>),
}

/// Runs `$body` with `$v` bound to the typed vector of any variant.
macro_rules! each {
    ($data:expr, $v:ident => $body:expr) => {
        match $data {
            VoxelData::U8($v) => $body,
            VoxelData::I8($v) => $body,
            VoxelData::U16($v) => $body,
            VoxelData::I16($v) => $body,
            VoxelData::U32($v) => $body,
            VoxelData::I32($v) => $body,
            VoxelData::F32($v) => $body,
            VoxelData::F64($v) => $body,
        }
    };
}

// `f64::from` is the identity for the `F64` arm of `each!`.
#[allow(clippy::useless_conversion)]
impl VoxelData {
    /// Decodes packed values of type `ty` (`bytes.len()` must be a multiple of its size; a
    /// trailing partial value is ignored).
    pub fn from_bytes(bytes: &[u8], ty: ScalarType, big_endian: bool) -> Self {
        macro_rules! decode {
            ($t:ty, $variant:ident) => {{
                const N: usize = size_of::<$t>();
                VoxelData::$variant(
                    bytes
                        .chunks_exact(N)
                        .map(|c| {
                            let mut a = [0u8; N];
                            a.copy_from_slice(c);
                            if big_endian {
                                <$t>::from_be_bytes(a)
                            } else {
                                <$t>::from_le_bytes(a)
                            }
                        })
                        .collect(),
                )
            }};
        }
        match ty {
            ScalarType::U8 => VoxelData::U8(bytes.to_vec()),
            ScalarType::I8 => decode!(i8, I8),
            ScalarType::U16 => decode!(u16, U16),
            ScalarType::I16 => decode!(i16, I16),
            ScalarType::U32 => decode!(u32, U32),
            ScalarType::I32 => decode!(i32, I32),
            ScalarType::F32 => decode!(f32, F32),
            ScalarType::F64 => decode!(f64, F64),
        }
    }

    /// The values as packed bytes in the given byte order.
    pub fn to_bytes(&self, big_endian: bool) -> Vec<u8> {
        each!(self, v => {
            let mut out = Vec::with_capacity(v.len() * self.scalar_type().size());
            for x in v {
                if big_endian {
                    out.extend_from_slice(&x.to_be_bytes());
                } else {
                    out.extend_from_slice(&x.to_le_bytes());
                }
            }
            out
        })
    }

    pub fn scalar_type(&self) -> ScalarType {
        match self {
            Self::U8(_) => ScalarType::U8,
            Self::I8(_) => ScalarType::I8,
            Self::U16(_) => ScalarType::U16,
            Self::I16(_) => ScalarType::I16,
            Self::U32(_) => ScalarType::U32,
            Self::I32(_) => ScalarType::I32,
            Self::F32(_) => ScalarType::F32,
            Self::F64(_) => ScalarType::F64,
        }
    }

    pub fn len(&self) -> usize {
        each!(self, v => v.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value at a linear offset as `f64` (exact for every type but nothing).
    pub fn get_f64(&self, offset: usize) -> Option<f64> {
        each!(self, v => v.get(offset).map(|&x| f64::from(x)))
    }

    /// Smallest and largest value, ignoring NaN; `None` when empty or all NaN.
    pub fn value_range(&self) -> Option<(f64, f64)> {
        each!(self, v => v.iter().map(|&x| f64::from(x)).filter(|x| !x.is_nan()).fold(None, |acc, x| {
            Some(match acc {
                None => (x, x),
                Some((lo, hi)) => (x.min(lo), x.max(hi)),
            })
        }))
    }

    /// All values as `f32` (rounded for 32-bit integers and `f64`).
    pub fn to_f32(&self) -> Vec<f32> {
        each!(self, v => v.iter().map(|&x| f64::from(x) as f32).collect())
    }

    /// All values as `f64` (exact).
    pub fn to_f64(&self) -> Vec<f64> {
        each!(self, v => v.iter().map(|&x| f64::from(x)).collect())
    }

    /// All values as labels: each must be an integer in `0..=65535`.
    pub fn to_labels(&self) -> Result<Vec<u16>, ErrorKind> {
        if let Self::U16(v) = self {
            return Ok(v.clone());
        }
        let mut out = Vec::with_capacity(self.len());
        each!(self, v => {
            for (i, &x) in v.iter().enumerate() {
                let f = f64::from(x);
                if f.fract() != 0.0 || !(0.0..=65535.0).contains(&f) {
                    return Err(ErrorKind::NotLabels(format!(
                        "voxel {i} has value {f}, not an integer in 0..=65535"
                    )));
                }
                out.push(f as u16);
            }
        });
        Ok(out)
    }
}

/// An image: its grid and its voxel values (`data.len() == grid.len()`).
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    grid: Grid,
    data: VoxelData,
}

impl Image {
    /// An image from a grid and matching data.
    pub fn new(grid: Grid, data: VoxelData) -> Result<Self, GeomError> {
        if data.len() != grid.len() {
            return Err(GeomError::DataLength {
                expected: grid.len(),
                got: data.len(),
            });
        }
        Ok(Self { grid, data })
    }

    /// A `u16` image of a label map.
    pub fn from_label_map(labels: &LabelMap) -> Self {
        Self {
            grid: labels.grid().clone(),
            data: VoxelData::U16(labels.data().to_vec()),
        }
    }

    /// An `f32` image of a float volume.
    pub fn from_volume_f32(volume: &Volume<f32>) -> Self {
        Self {
            grid: volume.grid().clone(),
            data: VoxelData::F32(volume.data().to_vec()),
        }
    }

    pub fn grid(&self) -> &Grid {
        &self.grid
    }
    pub fn data(&self) -> &VoxelData {
        &self.data
    }
    pub fn into_parts(self) -> (Grid, VoxelData) {
        (self.grid, self.data)
    }

    /// Smallest and largest voxel value (NaN ignored).
    pub fn value_range(&self) -> Option<(f64, f64)> {
        self.data.value_range()
    }

    /// The label map of this image: every value must be an integer in `0..=65535` (floats
    /// included, as long as each is integral), else [`ErrorKind::NotLabels`].
    pub fn to_label_map(&self) -> Result<LabelMap, ErrorKind> {
        let labels = self.data.to_labels()?;
        Ok(Volume::from_vec(self.grid.clone(), labels)?)
    }

    /// The values as an `f32` volume.
    pub fn to_volume_f32(&self) -> Volume<f32> {
        self.to_volume(self.data.to_f32())
    }

    /// The values as an `f64` volume.
    pub fn to_volume_f64(&self) -> Volume<f64> {
        self.to_volume(self.data.to_f64())
    }

    fn to_volume<T: Copy + Default>(&self, data: Vec<T>) -> Volume<T> {
        // The length matches by construction; fall back to an empty-valued volume otherwise.
        Volume::from_vec(self.grid.clone(), data)
            .unwrap_or_else(|_| Volume::filled(self.grid.clone(), T::default()))
    }
}

impl From<&LabelMap> for Image {
    fn from(labels: &LabelMap) -> Self {
        Self::from_label_map(labels)
    }
}

impl From<&Volume<f32>> for Image {
    fn from(volume: &Volume<f32>) -> Self {
        Self::from_volume_f32(volume)
    }
}
