//! Blob compression with bounded decompression.

use crate::{StoreError, StoreOptions};

/// A blob's bytes as stored: zstd frame and the uncompressed length.
#[derive(Debug, Clone)]
pub(crate) struct Packed {
    pub raw_len: u64,
    pub data: Vec<u8>,
}

pub(crate) fn pack(opts: &StoreOptions, data: &[u8]) -> Result<Packed, StoreError> {
    let raw_len = data.len() as u64;
    if raw_len > opts.max_blob_bytes {
        return Err(StoreError::TooLarge {
            what: "blob",
            size: raw_len,
            limit: opts.max_blob_bytes,
        });
    }
    let data = zstd::bulk::compress(data, opts.zstd_level)
        .map_err(|e| StoreError::Backend(format!("zstd compression failed: {e}")))?;
    Ok(Packed { raw_len, data })
}

/// [`pack`], refused when the compressed bytes exceed a backend's largest value (`limit`);
/// with the uncompressed length as a database integer.
pub(crate) fn pack_within(
    opts: &StoreOptions,
    data: &[u8],
    limit: u64,
) -> Result<(Packed, i64), StoreError> {
    let packed = pack(opts, data)?;
    if packed.data.len() as u64 > limit {
        return Err(StoreError::TooLarge {
            what: "compressed blob",
            size: packed.data.len() as u64,
            limit,
        });
    }
    let raw_len = crate::to_i64("blob length", packed.raw_len)?;
    Ok((packed, raw_len))
}

/// Inflates a stored blob, allocating only the recorded length and only if within the limit.
pub(crate) fn unpack(
    opts: &StoreOptions,
    raw_len: u64,
    data: &[u8],
) -> Result<Vec<u8>, StoreError> {
    if raw_len > opts.max_blob_bytes {
        return Err(StoreError::TooLarge {
            what: "stored blob",
            size: raw_len,
            limit: opts.max_blob_bytes,
        });
    }
    let cap = usize::try_from(raw_len).map_err(|_| StoreError::TooLarge {
        what: "stored blob",
        size: raw_len,
        limit: usize::MAX as u64,
    })?;
    let out = zstd::bulk::decompress(data, cap).map_err(|e| StoreError::Corrupt {
        detail: format!("blob of {raw_len} bytes does not decompress: {e}"),
    })?;
    if out.len() != cap {
        return Err(StoreError::Corrupt {
            detail: format!(
                "blob decompressed to {} bytes, its recorded length is {raw_len}",
                out.len()
            ),
        });
    }
    Ok(out)
}
