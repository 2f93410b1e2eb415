//! Assembly of a label-map upload (a gRPC client stream of chunks, or an HTTP body): the header
//! fixes what comes and how much; every chunk is checked before its bytes are kept, so an
//! oversized or overlong upload is refused before it is buffered. The operation layer sees the
//! upload only once it is complete.

use resecta_api::MAX_CHUNK_BYTES;
use resecta_api::v1 as pb;
use resecta_api::v1::upload_label_map_request::Header;
use resecta_geom::RoleMap;
use resecta_session::api::{LabelMapSource, RawLabelMap};

use crate::convert::{self, RawGeometry};
use crate::error::WireError;

/// Most bytes reserved up front, whatever `total_bytes` claims; the buffer grows beyond this as
/// data arrives.
const PREALLOCATE_BYTES: u64 = 64 << 20;

#[derive(Debug)]
enum Kind {
    Raw(RawGeometry),
    File(resecta_session::api::FileFormat),
}

/// An upload in progress.
#[derive(Debug)]
pub struct Upload {
    pub session_id: String,
    roles: RoleMap,
    kind: Kind,
    total_bytes: u64,
    data: Vec<u8>,
}

impl Upload {
    /// Starts from the first chunk's header; refuses uploads beyond `max_upload_bytes`.
    pub fn start(header: Option<&Header>, max_upload_bytes: u64) -> Result<Self, WireError> {
        let (session_id, roles, kind, total_bytes) = match header {
            None => {
                return Err(WireError::bad_chunk(
                    "header",
                    "the first chunk must carry the header (raw or file)",
                ));
            }
            Some(Header::Raw(h)) => (
                h.session_id.clone(),
                convert::role_map("raw.roles", h.roles.as_ref())?,
                Kind::Raw(convert::raw_geometry(h)?),
                h.total_bytes,
            ),
            Some(Header::File(h)) => (
                h.session_id.clone(),
                convert::role_map("file.roles", h.roles.as_ref())?,
                Kind::File(convert::file_format(h.format)?),
                h.total_bytes,
            ),
        };
        if total_bytes > max_upload_bytes {
            return Err(WireError::TooLarge(format!(
                "an upload of {total_bytes} bytes exceeds the server's limit of {max_upload_bytes} bytes"
            )));
        }
        Ok(Self {
            session_id,
            roles,
            kind,
            total_bytes,
            data: Vec::with_capacity(total_bytes.min(PREALLOCATE_BYTES) as usize),
        })
    }

    /// Appends one chunk's data (gRPC: at most [`MAX_CHUNK_BYTES`]).
    pub fn push(&mut self, msg: pb::UploadLabelMapRequest, first: bool) -> Result<(), WireError> {
        if !first && msg.header.is_some() {
            return Err(WireError::bad_chunk(
                "header",
                "only the first chunk carries a header",
            ));
        }
        let n = msg.data.len();
        if n > MAX_CHUNK_BYTES {
            return Err(WireError::bad_chunk(
                "data",
                format!("a chunk carries {n} bytes; at most {MAX_CHUNK_BYTES} are allowed"),
            ));
        }
        self.append(&msg.data)
    }

    /// Appends data of any length.
    pub fn append(&mut self, data: &[u8]) -> Result<(), WireError> {
        self.check(data)?;
        self.data.extend_from_slice(data);
        Ok(())
    }

    /// Appends data of any length, without a copy when it is the first (the HTTP face's body,
    /// already bounded by the upload limit).
    pub fn append_owned(&mut self, data: Vec<u8>) -> Result<(), WireError> {
        self.check(&data)?;
        if self.data.is_empty() {
            self.data = data;
        } else {
            self.data.extend_from_slice(&data);
        }
        Ok(())
    }

    fn check(&self, data: &[u8]) -> Result<(), WireError> {
        let received = self.data.len() as u64 + data.len() as u64;
        if received > self.total_bytes {
            return Err(WireError::bad_chunk(
                "data",
                format!(
                    "the chunks carry more than total_bytes ({})",
                    self.total_bytes
                ),
            ));
        }
        if let Kind::Raw(RawGeometry {
            signed_bytes: true, ..
        }) = self.kind
            && data.iter().any(|&b| b >= 0x80)
        {
            return Err(WireError::invalid(
                "data",
                "INT8 data holds negative labels",
            ));
        }
        Ok(())
    }

    /// The complete upload for the operation layer.
    pub fn finish(self) -> Result<(String, LabelMapSource, RoleMap), WireError> {
        if self.data.len() as u64 != self.total_bytes {
            return Err(WireError::bad_chunk(
                "data",
                format!(
                    "the stream ended after {} of total_bytes ({}) bytes",
                    self.data.len(),
                    self.total_bytes
                ),
            ));
        }
        let source = match self.kind {
            Kind::Raw(g) => LabelMapSource::Raw(RawLabelMap {
                dims: g.dims,
                spacing: g.spacing,
                origin: g.origin,
                direction: g.direction,
                data_type: g.data_type,
                data: self.data,
            }),
            Kind::File(format) => LabelMapSource::File {
                format,
                bytes: self.data,
            },
        };
        Ok((self.session_id, source, self.roles))
    }
}
