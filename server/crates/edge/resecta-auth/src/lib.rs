//! The access policy both server faces apply before any operation: an optional bearer token
//! (compared in constant time) and the API version a client says it speaks. The gRPC face reads
//! both from request metadata, the HTTP face from headers; the answers are the same.

use subtle::ConstantTimeEq;

pub use resecta_api::{API_VERSION_HEADER, API_VERSION_HEADER_VALUE};

/// Shortest accepted token (characters).
pub const MIN_TOKEN_CHARS: usize = 16;

/// Why a request was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AccessError {
    #[error("this server requires a bearer token (authorization: Bearer <token>)")]
    MissingToken,
    #[error("the authorization header is not of the form 'Bearer <token>'")]
    MalformedToken,
    #[error("the bearer token is not valid for this server")]
    WrongToken,
    #[error(
        "the client speaks API version {client:?} but this server speaks {server:?} (resecta.v1); \
         upgrade the client or the server"
    )]
    VersionMismatch {
        client: String,
        server: &'static str,
    },
}

impl AccessError {
    /// Authentication failures (401 / UNAUTHENTICATED), as opposed to a version mismatch.
    pub fn is_auth(&self) -> bool {
        !matches!(self, Self::VersionMismatch { .. })
    }

    /// Stable machine-readable code (`ErrorInfo.code`, problem `type`).
    pub fn code(&self) -> &'static str {
        match self {
            Self::MissingToken | Self::MalformedToken | Self::WrongToken => "UNAUTHENTICATED",
            Self::VersionMismatch { .. } => "API_VERSION_MISMATCH",
        }
    }
}

/// A token that is too short to configure.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("a bearer token needs at least {MIN_TOKEN_CHARS} characters (it has {0})")]
pub struct WeakToken(pub usize);

/// Who may call the server.
#[derive(Clone, Default)]
pub struct AccessPolicy {
    token: Option<Box<[u8]>>,
}

impl std::fmt::Debug for AccessPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AccessPolicy")
            .field("requires_token", &self.requires_token())
            .finish()
    }
}

impl AccessPolicy {
    /// Everybody (loopback workstation use).
    pub fn open() -> Self {
        Self::default()
    }

    /// Requests must carry `token`.
    pub fn with_token(token: &str) -> Result<Self, WeakToken> {
        let token = token.trim();
        let chars = token.chars().count();
        if chars < MIN_TOKEN_CHARS {
            return Err(WeakToken(chars));
        }
        Ok(Self {
            token: Some(token.as_bytes().into()),
        })
    }

    pub fn requires_token(&self) -> bool {
        self.token.is_some()
    }

    /// Checks the value of an `authorization` header (absent: `None`).
    pub fn check_authorization(&self, header: Option<&str>) -> Result<(), AccessError> {
        let Some(expected) = &self.token else {
            return Ok(());
        };
        let header = header.ok_or(AccessError::MissingToken)?;
        let (scheme, given) = header
            .trim()
            .split_once(' ')
            .ok_or(AccessError::MalformedToken)?;
        if !scheme.eq_ignore_ascii_case("bearer") {
            return Err(AccessError::MalformedToken);
        }
        if bool::from(given.trim().as_bytes().ct_eq(expected)) {
            Ok(())
        } else {
            Err(AccessError::WrongToken)
        }
    }

    /// Checks the token and the API version header (absent: accepted).
    pub fn check(
        &self,
        authorization: Option<&str>,
        api_version: Option<&str>,
    ) -> Result<(), AccessError> {
        self.check_authorization(authorization)?;
        check_api_version(api_version)
    }
}

/// Accepts an absent version header or [`API_VERSION_HEADER_VALUE`].
pub fn check_api_version(value: Option<&str>) -> Result<(), AccessError> {
    match value.map(str::trim) {
        None => Ok(()),
        Some(v) if v == API_VERSION_HEADER_VALUE => Ok(()),
        Some(v) => Err(AccessError::VersionMismatch {
            client: v.chars().take(32).collect(),
            server: API_VERSION_HEADER_VALUE,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: &str = "0123456789abcdef-token";

    #[test]
    fn open_policy_accepts_anything() {
        let p = AccessPolicy::open();
        assert!(!p.requires_token());
        assert_eq!(p.check_authorization(None), Ok(()));
        assert_eq!(p.check_authorization(Some("Bearer nonsense")), Ok(()));
    }

    #[test]
    fn token_policy() {
        let p = AccessPolicy::with_token(T).unwrap();
        assert!(p.requires_token());
        assert_eq!(p.check_authorization(Some(&format!("Bearer {T}"))), Ok(()));
        assert_eq!(
            p.check_authorization(Some(&format!("bearer  {T} "))),
            Ok(())
        );
        assert_eq!(p.check_authorization(None), Err(AccessError::MissingToken));
        assert_eq!(
            p.check_authorization(Some(T)),
            Err(AccessError::MalformedToken)
        );
        assert_eq!(
            p.check_authorization(Some(&format!("Basic {T}"))),
            Err(AccessError::MalformedToken)
        );
        assert_eq!(
            p.check_authorization(Some("Bearer 0123456789abcdef-tokeN")),
            Err(AccessError::WrongToken)
        );
        assert_eq!(
            p.check_authorization(Some("Bearer 0123456789abcdef")),
            Err(AccessError::WrongToken)
        );
    }

    #[test]
    fn short_tokens_are_refused() {
        assert_eq!(AccessPolicy::with_token("short").unwrap_err(), WeakToken(5));
        assert!(AccessPolicy::with_token("   ").is_err());
    }

    #[test]
    fn version_header() {
        assert_eq!(check_api_version(None), Ok(()));
        assert_eq!(check_api_version(Some("v1")), Ok(()));
        let e = check_api_version(Some("v2")).unwrap_err();
        assert!(!e.is_auth());
        assert_eq!(e.code(), "API_VERSION_MISMATCH");
        assert!(e.to_string().contains("\"v2\""), "{e}");
        let p = AccessPolicy::with_token(T).unwrap();
        assert_eq!(
            p.check(None, Some("v2")),
            Err(AccessError::MissingToken),
            "auth is checked first"
        );
    }

    #[test]
    fn debug_hides_the_token() {
        let p = AccessPolicy::with_token(T).unwrap();
        assert!(!format!("{p:?}").contains("token\""));
        assert!(!format!("{p:?}").contains(T));
    }
}
