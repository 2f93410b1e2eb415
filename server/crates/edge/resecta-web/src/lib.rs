//! The browser client (issue #20): the bundle in `web/dist` — built from `web/` by
//! `npm run build`, committed, and checked fresh by `scripts/test.sh` — compiled into the binary
//! (in every profile) and served by the HTTP face at `/`, on the API's origin, so the page uses
//! the server's own TLS and token. Each file of the bundle is one exact route (`/` is
//! `index.html`); answers carry an `ETag` (the file's SHA-256), are revalidated on every load
//! (`Cache-Control: no-cache`, `304` on a match) and forbid framing, sniffing and other origins.

use axum::Router;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use rust_embed::RustEmbed;

#[derive(RustEmbed)]
#[folder = "../../../../web/dist"]
struct Bundle;

/// The page's entry file, also served at `/`.
pub const INDEX: &str = "index.html";

/// What the page may load: only its own origin (scripts, styles, the API and its event
/// streams); images also from `data:`/`blob:` URLs (screenshots, textures).
const CSP: &str = "default-src 'self'; img-src 'self' data: blob:; style-src 'self'; \
                   script-src 'self'; connect-src 'self'; worker-src 'self' blob:; \
                   frame-ancestors 'none'; base-uri 'none'; form-action 'self'";

/// Routes of every bundle file (and `/` for [`INDEX`]), for any router state.
pub fn router<S: Clone + Send + Sync + 'static>() -> Router<S> {
    let mut router = Router::new();
    for name in Bundle::iter() {
        let file = name.to_string();
        let path = format!("/{file}");
        if file == INDEX {
            let index = file.clone();
            router = router.route("/", get(move |h: HeaderMap| serve(index, h)));
        }
        router = router.route(&path, get(move |h: HeaderMap| serve(file, h)));
    }
    router
}

/// Names of the bundle's files.
pub fn files() -> Vec<String> {
    Bundle::iter().map(|f| f.to_string()).collect()
}

fn content_type(file: &str) -> &'static str {
    match file.rsplit_once('.').map(|(_, ext)| ext) {
        Some("html") => "text/html; charset=utf-8",
        Some("js" | "mjs") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("json") => "application/json",
        Some("svg") => "image/svg+xml",
        Some("png") => "image/png",
        Some("ico") => "image/x-icon",
        Some("wasm") => "application/wasm",
        _ => "application/octet-stream",
    }
}

async fn serve(file: String, request: HeaderMap) -> Response {
    let Some(asset) = Bundle::get(&file) else {
        return StatusCode::NOT_FOUND.into_response();
    };
    let hash: String = asset
        .metadata
        .sha256_hash()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    let etag = format!("\"{hash}\"");
    let headers = [
        (header::ETAG, etag.clone()),
        (header::CACHE_CONTROL, "no-cache".to_owned()),
        (header::CONTENT_SECURITY_POLICY, CSP.to_owned()),
        (header::X_CONTENT_TYPE_OPTIONS, "nosniff".to_owned()),
        (header::X_FRAME_OPTIONS, "DENY".to_owned()),
        (header::REFERRER_POLICY, "no-referrer".to_owned()),
    ];
    let fresh = request
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|tag| tag.trim() == etag || tag.trim() == "*");
    if fresh {
        return (StatusCode::NOT_MODIFIED, headers).into_response();
    }
    let mut response = (headers, asset.data.into_owned()).into_response();
    response.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(content_type(&file)),
    );
    response
}

#[cfg(test)]
mod tests {
    use axum::body::{Body, to_bytes};
    use axum::http::Request;
    use tower::ServiceExt;

    use super::*;

    async fn get(path: &str, etag: Option<&str>) -> Response {
        let mut req = Request::get(path);
        if let Some(tag) = etag {
            req = req.header(header::IF_NONE_MATCH, tag);
        }
        router::<()>()
            .oneshot(req.body(Body::empty()).unwrap())
            .await
            .unwrap()
    }

    #[tokio::test]
    async fn the_page_is_served_at_the_root_with_its_files() {
        let files = files();
        assert!(files.iter().any(|f| f == INDEX), "{files:?}");
        let root = get("/", None).await;
        assert_eq!(root.status(), StatusCode::OK);
        let h = root.headers();
        assert_eq!(h[header::CONTENT_TYPE], "text/html; charset=utf-8");
        assert_eq!(h[header::X_CONTENT_TYPE_OPTIONS], "nosniff");
        assert!(
            h[header::CONTENT_SECURITY_POLICY]
                .to_str()
                .unwrap()
                .contains("frame-ancestors 'none'")
        );
        let html = to_bytes(root.into_body(), usize::MAX).await.unwrap();
        let same = to_bytes(get("/index.html", None).await.into_body(), usize::MAX)
            .await
            .unwrap();
        assert_eq!(html, same);
        // Every script and stylesheet the page names is served, with its type.
        let html = String::from_utf8(html.to_vec()).unwrap();
        for file in files
            .iter()
            .filter(|f| f.ends_with(".js") || f.ends_with(".css"))
        {
            assert!(
                html.contains(file.as_str()),
                "the page does not load {file}"
            );
            let r = get(&format!("/{file}"), None).await;
            assert_eq!(r.status(), StatusCode::OK);
            assert_ne!(
                r.headers()[header::CONTENT_TYPE],
                "application/octet-stream"
            );
        }
        assert_eq!(
            get("/no-such-file.js", None).await.status(),
            StatusCode::NOT_FOUND
        );
    }

    #[tokio::test]
    async fn a_known_version_is_not_sent_again() {
        let first = get("/", None).await;
        let etag = first.headers()[header::ETAG].to_str().unwrap().to_owned();
        assert_eq!(etag.len(), 66, "a quoted SHA-256: {etag}");
        let again = get("/", Some(&etag)).await;
        assert_eq!(again.status(), StatusCode::NOT_MODIFIED);
        assert!(
            to_bytes(again.into_body(), usize::MAX)
                .await
                .unwrap()
                .is_empty()
        );
        let listed = get("/", Some(&format!("\"stale\", {etag}"))).await;
        assert_eq!(listed.status(), StatusCode::NOT_MODIFIED);
        assert_eq!(get("/", Some("\"stale\"")).await.status(), StatusCode::OK);
    }

    #[test]
    fn content_types_follow_the_extension() {
        assert_eq!(content_type("app.js"), "text/javascript; charset=utf-8");
        assert_eq!(content_type("app.css"), "text/css; charset=utf-8");
        assert_eq!(content_type("LICENSE"), "application/octet-stream");
    }
}
