//! The web dashboard: static files embedded in the binary (`assets/dashboard/`), served at `/`
//! (the page) and `/assets/…` (its ES modules, stylesheet and the vendored uPlot). Nothing is
//! built at run time and nothing is read from disk; the page talks only to the documented API
//! (`openapi.yaml`) with the user's bearer token, so serving it needs no token.
//!
//! Every response carries `Cache-Control: no-cache` and an `ETag` (a hash of the file), so a
//! browser revalidates (`If-None-Match` → 304) and never runs a page older than the binary.

use crate::error::ApiError;
use crate::AppState;
use axum::extract::Path;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use std::sync::OnceLock;

/// One embedded file: its path under `assets/dashboard/` (and under `/assets/` in URLs).
struct Asset {
    path: &'static str,
    bytes: &'static [u8],
}

macro_rules! assets {
    ($($path:literal),* $(,)?) => {
        &[$(Asset {
            path: $path,
            bytes: include_bytes!(concat!("../assets/dashboard/", $path)),
        }),*]
    };
}

/// Every file of the dashboard (a test holds this list equal to the directory).
static ASSETS: &[Asset] = assets![
    "index.html",
    "style.css",
    "app.js",
    "api.js",
    "util.js",
    "actions.js",
    "images.js",
    "jobs.js",
    "job.js",
    "workers.js",
    "submit.js",
    "charts.js",
    "frames.js",
    "vendor/uplot/uPlot.esm.js",
    "vendor/uplot/uPlot.min.css",
    "vendor/uplot/LICENSE",
];

/// The page may load its own scripts, styles and API responses, and show images from object
/// URLs (`blob:`), and nothing else; nobody may frame it.
const CSP: &str =
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; \
                   connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'";

/// `GET /` and `GET /assets/{*path}`.
pub fn router() -> Router<AppState> {
    routes()
}

fn routes<S: Clone + Send + Sync + 'static>() -> Router<S> {
    Router::new()
        .route("/", get(|headers: HeaderMap| async move { serve("index.html", &headers) }))
        .route(
            "/assets/{*path}",
            get(|Path(path): Path<String>, headers: HeaderMap| async move {
                serve(&path, &headers)
            }),
        )
}

fn content_type(path: &str) -> &'static str {
    match path.rsplit_once('.').map(|(_, ext)| ext) {
        Some("html") => "text/html; charset=utf-8",
        Some("js") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("svg") => "image/svg+xml",
        Some("png") => "image/png",
        _ => "text/plain; charset=utf-8",
    }
}

/// FNV-1a 64 of each asset, quoted: stable for a given build, different when the file changes.
fn etag(index: usize) -> &'static str {
    static ETAGS: OnceLock<Vec<String>> = OnceLock::new();
    &ETAGS.get_or_init(|| {
        ASSETS
            .iter()
            .map(|a| {
                let h = a.bytes.iter().fold(0xcbf2_9ce4_8422_2325_u64, |h, &b| {
                    (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
                });
                format!("\"d{h:016x}\"")
            })
            .collect()
    })[index]
}

fn serve(path: &str, request: &HeaderMap) -> Response {
    let Some(index) = ASSETS.iter().position(|a| a.path == path) else {
        return ApiError::not_found("dashboard asset", path).into_response();
    };
    let asset = &ASSETS[index];
    let tag = etag(index);
    let fresh = request
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|t| t.trim() == tag || t.trim() == "*");
    let mut headers = HeaderMap::new();
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    headers.insert(header::ETAG, HeaderValue::from_static(tag));
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    if fresh {
        return (StatusCode::NOT_MODIFIED, headers).into_response();
    }
    headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(content_type(path)),
    );
    if path.ends_with(".html") {
        headers.insert(
            header::CONTENT_SECURITY_POLICY,
            HeaderValue::from_static(CSP),
        );
        headers.insert(
            header::REFERRER_POLICY,
            HeaderValue::from_static("no-referrer"),
        );
    }
    (headers, asset.bytes).into_response()
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::body::Body;
    use axum::http::Request;
    use http_body_util::BodyExt;
    use std::collections::BTreeSet;
    use std::path::{Path as FsPath, PathBuf};
    use tower::ServiceExt;

    fn dir() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/dashboard")
    }

    fn files(root: &FsPath, dir: &FsPath, out: &mut BTreeSet<String>) {
        for entry in std::fs::read_dir(dir).expect("read the assets directory") {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                files(root, &path, out);
            } else if path.file_name().is_some_and(|n| n != "README.md") {
                let rel = path.strip_prefix(root).expect("inside the root");
                out.insert(rel.to_string_lossy().replace('\\', "/"));
            }
        }
    }

    /// A file added to `assets/dashboard/` but not to `ASSETS` would be a 404 in the browser.
    #[test]
    fn every_file_is_embedded() {
        let mut on_disk = BTreeSet::new();
        files(&dir(), &dir(), &mut on_disk);
        let embedded: BTreeSet<String> = ASSETS.iter().map(|a| a.path.to_string()).collect();
        assert_eq!(on_disk, embedded);
    }

    /// Every relative `import … from './x.js'` of every module names an embedded file.
    #[test]
    fn module_imports_resolve() {
        for a in ASSETS.iter().filter(|a| a.path.ends_with(".js")) {
            let text = std::str::from_utf8(a.bytes).expect("UTF-8 JavaScript");
            let base = a.path.rsplit_once('/').map_or("", |(d, _)| d);
            for line in text.lines() {
                let line = line.trim();
                let Some(rest) = line
                    .split(" from '")
                    .nth(1)
                    .filter(|_| line.starts_with("import ") || line.starts_with("} from "))
                else {
                    continue;
                };
                let Some(spec) = rest.split('\'').next().filter(|s| s.starts_with("./")) else {
                    continue;
                };
                let target = match base {
                    "" => spec[2..].to_string(),
                    d => format!("{d}/{}", &spec[2..]),
                };
                assert!(
                    ASSETS.iter().any(|x| x.path == target),
                    "{} imports {spec}, which is not embedded",
                    a.path
                );
            }
        }
    }

    async fn get(uri: &str, if_none_match: Option<&str>) -> Response {
        let mut req = Request::get(uri);
        if let Some(t) = if_none_match {
            req = req.header(header::IF_NONE_MATCH, t);
        }
        routes::<()>()
            .oneshot(req.body(Body::empty()).expect("request"))
            .await
            .expect("infallible")
    }

    #[tokio::test]
    async fn serves_the_page_and_its_assets() {
        let page = get("/", None).await;
        assert_eq!(page.status(), StatusCode::OK);
        assert_eq!(
            page.headers()[header::CONTENT_TYPE],
            "text/html; charset=utf-8"
        );
        assert_eq!(page.headers()[header::CACHE_CONTROL], "no-cache");
        assert!(page.headers().contains_key(header::CONTENT_SECURITY_POLICY));
        let body = page.into_body().collect().await.expect("body").to_bytes();
        assert!(body.starts_with(b"<!doctype html>"));

        let js = get("/assets/app.js", None).await;
        assert_eq!(js.status(), StatusCode::OK);
        assert_eq!(
            js.headers()[header::CONTENT_TYPE],
            "text/javascript; charset=utf-8"
        );
        let tag = js.headers()[header::ETAG]
            .to_str()
            .expect("ETag")
            .to_string();
        let again = get("/assets/app.js", Some(&tag)).await;
        assert_eq!(again.status(), StatusCode::NOT_MODIFIED);
        assert_eq!(again.headers()[header::ETAG], tag.as_str());
        assert_eq!(
            get("/assets/app.js", Some("\"other\"")).await.status(),
            StatusCode::OK
        );

        let css = get("/assets/vendor/uplot/uPlot.min.css", None).await;
        assert_eq!(
            css.headers()[header::CONTENT_TYPE],
            "text/css; charset=utf-8"
        );
        let licence = get("/assets/vendor/uplot/LICENSE", None).await;
        assert_eq!(licence.status(), StatusCode::OK);
        assert_eq!(
            licence.headers()[header::CONTENT_TYPE],
            "text/plain; charset=utf-8"
        );
    }

    #[tokio::test]
    async fn unknown_assets_are_json_404s() {
        for uri in [
            "/assets/nope.js",
            "/assets/../Cargo.toml",
            "/assets/vendor/uplot/README.md",
        ] {
            let resp = get(uri, None).await;
            assert_eq!(resp.status(), StatusCode::NOT_FOUND, "{uri}");
            let body = resp.into_body().collect().await.expect("body").to_bytes();
            let v: serde_json::Value = serde_json::from_slice(&body).expect("JSON error body");
            assert_eq!(v["error"]["code"], "not_found", "{uri}");
        }
    }
}
