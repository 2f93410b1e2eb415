//! The binary wire format of surfaces that the planning server streams to clients: a full
//! snapshot ([`encode_mesh`], magic `RSMS`) and then per-edit deltas ([`encode_delta`], magic
//! `RSDL`) carrying only the changed vertices, exact f32 or quantised, optionally zstd; and a
//! bounded [`ReplayRing`] for clients that reconnect. Little-endian, 4-byte aligned sections,
//! specified in `docs/wire/mesh-delta.md` so numpy can decode them with `frombuffer`.
//!
//! Decoders validate every count against the message length and [`DecodeLimits`] before they
//! allocate, check triangle indices, and return [`DeltaError`] on bad input, never panic.

mod codec;
mod error;
mod format;
mod frame;
mod quant;
mod ring;

pub use codec::{DeltaStats, apply_delta, decode_mesh, encode_delta, encode_mesh};
pub use error::DeltaError;
pub use format::{DELTA_MAGIC, HEADER_BYTES, Header, Kind, MESH_MAGIC, VERSION, flags, inspect};
pub use frame::{DecodeLimits, EncodeOptions, Quantise, SurfaceFrame, Topology};
pub use quant::{QuantBox, oct_decode, oct_encode};
pub use ring::{ReplayRing, Since};
