//! What clients see of a surface: topology and per-vertex attributes, and the encoder settings.

use resecta_geom::TriMesh;
use serde::{Deserialize, Serialize};

use crate::error::DeltaError;
use crate::format::flags;

/// Per-vertex state of one surface as clients see it (f32, RAS mm). `normals`, `margins` and
/// `classes` hold one entry per position or none (models without normals or margins).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurfaceFrame {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    /// Distance to the nearest target tumour (mm).
    pub margins: Vec<f32>,
    /// Margin class per vertex (`resecta_margin::MarginClass` as u8).
    pub classes: Vec<u8>,
}

/// Triangles of a surface, indices into the frame's vertices.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Topology {
    pub triangles: Vec<[u32; 3]>,
}

impl SurfaceFrame {
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Flags of the attributes this frame carries (positions always).
    pub fn attribute_flags(&self) -> u16 {
        let mut f = flags::POSITIONS;
        if !self.normals.is_empty() {
            f |= flags::NORMALS;
        }
        if !self.margins.is_empty() {
            f |= flags::MARGINS;
        }
        if !self.classes.is_empty() {
            f |= flags::CLASSES;
        }
        f
    }

    /// Each optional attribute has one entry per vertex or none; the vertex count fits u32.
    pub fn validate(&self) -> Result<(), DeltaError> {
        let n = self.positions.len() as u64;
        if n > u64::from(u32::MAX) {
            return Err(DeltaError::TooLarge {
                what: "vertex",
                count: n,
                limit: u64::from(u32::MAX),
            });
        }
        for (what, len) in [
            ("normals", self.normals.len()),
            ("margins", self.margins.len()),
            ("classes", self.classes.len()),
        ] {
            if len != 0 && len as u64 != n {
                return Err(DeltaError::AttributeLength {
                    what,
                    len: len as u64,
                    expected: n,
                });
            }
        }
        Ok(())
    }

    /// A frame and topology from a mesh (f64 → f32); normals from the mesh or, when it has
    /// none, area-weighted vertex normals; no margins or classes.
    pub fn from_trimesh(mesh: &TriMesh) -> (Topology, SurfaceFrame) {
        let to32 = |v: &resecta_geom::Vec3| [v.x as f32, v.y as f32, v.z as f32];
        let normals = match mesh.normals() {
            Some(n) => n.iter().map(to32).collect(),
            None => mesh.compute_vertex_normals().iter().map(to32).collect(),
        };
        (
            Topology {
                triangles: mesh.triangles().to_vec(),
            },
            SurfaceFrame {
                positions: mesh.vertices().iter().map(to32).collect(),
                normals,
                margins: Vec::new(),
                classes: Vec::new(),
            },
        )
    }
}

/// Lossy quantisation of positions and normals; margins and classes stay exact.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Quantise {
    /// Positions as u16 codes over the box of the sent vertices: error per coordinate
    /// ≤ extent/131068 plus half an f32 ulp of the coordinate.
    pub positions: bool,
    /// Normals as octahedral snorm16 pairs: angular error ≤ 5e-5 rad (measured worst 4.3e-5).
    pub normals: bool,
}

impl Default for Quantise {
    fn default() -> Self {
        Self {
            positions: true,
            normals: true,
        }
    }
}

/// Encoder settings; the default is exact f32 without compression.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct EncodeOptions {
    pub quantise: Option<Quantise>,
    /// zstd level (1–22, or negative for the fast levels); the payload is compressed only
    /// when that makes the message smaller.
    pub zstd_level: Option<i32>,
}

impl EncodeOptions {
    pub fn exact() -> Self {
        Self::default()
    }

    pub fn quantised() -> Self {
        Self {
            quantise: Some(Quantise::default()),
            zstd_level: None,
        }
    }

    pub fn with_zstd(mut self, level: i32) -> Self {
        self.zstd_level = Some(level);
        self
    }

    pub(crate) fn quant_flags(&self) -> u16 {
        match self.quantise {
            None => 0,
            Some(q) => {
                (if q.positions { flags::POSITIONS_U16 } else { 0 })
                    | (if q.normals { flags::NORMALS_OCT16 } else { 0 })
            }
        }
    }
}

/// Bounds a decoder enforces before it allocates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct DecodeLimits {
    pub max_vertices: u32,
    pub max_triangles: u32,
}

impl Default for DecodeLimits {
    /// 8 M vertices and 16 M triangles (a snapshot of at most ~460 MB).
    fn default() -> Self {
        Self {
            max_vertices: 8 << 20,
            max_triangles: 16 << 20,
        }
    }
}
