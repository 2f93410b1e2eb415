//! Errors of the server process (start-up and listeners); request errors belong to the faces.

/// Why the server could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    #[error("configuration: {0}")]
    Config(String),
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        addr: std::net::SocketAddr,
        source: std::io::Error,
    },
    #[error("TLS: {0}")]
    Tls(String),
    #[error("session store: {0}")]
    Store(#[from] resecta_store::StoreError),
    #[error("{face} face: {message}")]
    Serve { face: &'static str, message: String },
    #[error("demo patient: {0}")]
    Demo(String),
    #[error("GPU: {0}")]
    Gpu(String),
}

impl ServerError {
    /// Whether the operator's input (flags, files) is at fault rather than the machine.
    pub fn is_bad_input(&self) -> bool {
        matches!(self, Self::Config(_) | Self::Tls(_))
    }
}
