//! The access check in front of `PlanningService`: [`AccessPolicy`] on the `authorization` and
//! `resecta-api-version` metadata of every call, before the request body is read. A tower
//! wrapper rather than a tonic interceptor because `GetServerInfo` must skip the version check,
//! and an interceptor cannot see the method. A call that passes marks its connection
//! authenticated ([`resecta_conn::Conn`], when the server put one into the extensions).

use std::convert::Infallible;
use std::sync::Arc;
use std::task::{Context, Poll};

use futures_util::future::{Either, Ready, ready};
use resecta_auth::{API_VERSION_HEADER, AccessError, AccessPolicy};
use tonic::server::NamedService;

use crate::error::access_status;

/// The one method that answers clients of any API version.
const SERVER_INFO_PATH: &str = "/resecta.v1.PlanningService/GetServerInfo";

/// `inner` behind the access policy.
#[derive(Debug, Clone)]
pub struct Access<S> {
    inner: S,
    policy: Arc<AccessPolicy>,
}

impl<S> Access<S> {
    pub fn new(inner: S, policy: AccessPolicy) -> Self {
        Self {
            inner,
            policy: Arc::new(policy),
        }
    }
}

impl<S: NamedService> NamedService for Access<S> {
    const NAME: &'static str = S::NAME;
}

/// A header's value; a value that is not visible ASCII counts as present but unusable.
fn header<'a, B>(req: &'a http::Request<B>, name: &str) -> Option<&'a str> {
    req.headers()
        .get(name)
        .map(|v| v.to_str().unwrap_or("\u{fffd}"))
}

fn check<B>(policy: &AccessPolicy, req: &http::Request<B>) -> Result<(), AccessError> {
    let authorization = header(req, "authorization");
    if req.uri().path() == SERVER_INFO_PATH {
        policy.check_authorization(authorization)
    } else {
        policy.check(authorization, header(req, API_VERSION_HEADER))
    }
}

impl<S, B> tower::Service<http::Request<B>> for Access<S>
where
    S: tower::Service<
            http::Request<B>,
            Response = http::Response<tonic::body::Body>,
            Error = Infallible,
        >,
{
    type Response = http::Response<tonic::body::Body>;
    type Error = Infallible;
    type Future = Either<S::Future, Ready<Result<Self::Response, Infallible>>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Infallible>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        match check(&self.policy, &req) {
            Ok(()) => {
                // The connection carried an authenticated call: no longer subject to the
                // handshake timeout nor evicted as unauthenticated (resecta-conn).
                if let Some(conn) = req.extensions().get::<resecta_conn::Conn>() {
                    conn.mark_authenticated();
                }
                Either::Left(self.inner.call(req))
            }
            Err(e) => {
                let method = crate::error::method_for_logs(req.uri().path());
                tracing::debug!(method, reason = e.code(), "call refused");
                Either::Right(ready(Ok(access_status(&e).into_http())))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use resecta_conn::{Admission, AdmitOn, ConnLimits};
    use tower::{Service, ServiceExt};

    use super::*;

    const TOKEN: &str = "unit-test-token-0123456789";

    fn call(auth: Option<&str>, conn: &resecta_conn::Conn) -> http::Request<()> {
        let mut req = http::Request::builder()
            .uri("/resecta.v1.PlanningService/ListSessions")
            .header(API_VERSION_HEADER, "v1");
        if let Some(a) = auth {
            req = req.header("authorization", a);
        }
        let mut req = req.body(()).unwrap();
        req.extensions_mut().insert(conn.clone());
        req
    }

    #[tokio::test]
    async fn only_an_authenticated_call_marks_its_connection() {
        let admission = Admission::new(ConnLimits::default(), AdmitOn::Authenticated);
        let conn = admission
            .admit("grpc", "127.0.0.1:40000".parse().unwrap())
            .unwrap();
        let inner = tower::service_fn(|_req: http::Request<()>| async {
            Ok::<_, Infallible>(http::Response::new(tonic::body::Body::empty()))
        });
        let mut access = Access::new(inner, AccessPolicy::with_token(TOKEN).unwrap());
        for refused in [None, Some("Bearer not-the-token-0123456789")] {
            let res = access.ready().await.unwrap().call(call(refused, &conn));
            let res = res.await.unwrap();
            assert_eq!(res.headers()["grpc-status"], "16");
            assert!(!conn.is_admitted());
        }
        assert_eq!(admission.unauthenticated(), 1);
        let bearer = format!("Bearer {TOKEN}");
        let res = access
            .ready()
            .await
            .unwrap()
            .call(call(Some(&bearer), &conn));
        assert!(res.await.unwrap().headers().get("grpc-status").is_none());
        assert!(conn.is_admitted());
        assert_eq!(admission.unauthenticated(), 0);
    }
}
