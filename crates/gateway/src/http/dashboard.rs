//! The web dashboard: one page of plain HTML, CSS and JavaScript embedded in the binary (no build
//! step, nothing fetched from the internet). The page talks only to the HTTP API of this
//! gateway: `GET /api/buses`, `/api/drives`, `/api/events`, `/api/drives/{id}/trend`, the live
//! stream `/api/stream`, and the command endpoints with the user's token (docs/dashboard.md).

use std::sync::Arc;

use axum::extract::Path;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

use crate::core::Gateway;

/// The page.
pub const INDEX_HTML: &str = include_str!("dashboard/index.html");
/// The page's script.
pub const APP_JS: &str = include_str!("dashboard/app.js");
/// The commissioning pages' script (a drive's parameters, backup and restore, compare, trips,
/// finding drives on a bus).
pub const WORKBENCH_JS: &str = include_str!("dashboard/workbench.js");
/// The page's style sheet.
pub const STYLE_CSS: &str = include_str!("dashboard/style.css");
/// The page's icon.
pub const FAVICON_SVG: &str = include_str!("dashboard/favicon.svg");

/// What the page may load and connect to: this gateway only.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; \
                   connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

/// The embedded asset at `/assets/<name>`: its content type and bytes.
pub fn asset(name: &str) -> Option<(&'static str, &'static str)> {
    Some(match name {
        "app.js" => ("text/javascript; charset=utf-8", APP_JS),
        "workbench.js" => ("text/javascript; charset=utf-8", WORKBENCH_JS),
        "style.css" => ("text/css; charset=utf-8", STYLE_CSS),
        "favicon.svg" => ("image/svg+xml", FAVICON_SVG),
        _ => return None,
    })
}

/// The dashboard's routes: `GET /` (the page) and `GET /assets/*` (its script, style and icon).
pub fn routes() -> Router<Arc<Gateway>> {
    Router::new()
        .route("/", get(index))
        .route("/index.html", get(index))
        .route("/assets/*name", get(asset_handler))
}

fn respond(content_type: &'static str, body: &'static str) -> Response {
    let mut r = body.into_response();
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    // The assets change with the binary: revalidate rather than keep a stale copy.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    h.insert(header::CONTENT_SECURITY_POLICY, HeaderValue::from_static(CSP));
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    r
}

async fn index() -> Response {
    respond("text/html; charset=utf-8", INDEX_HTML)
}

async fn asset_handler(Path(name): Path<String>) -> Response {
    match asset(&name) {
        Some((ct, body)) => respond(ct, body),
        None => {
            let message = format!(
                "no dashboard asset {name:?}: the page uses app.js, workbench.js, style.css and favicon.svg"
            );
            let body = serde_json::json!({ "error": { "kind": "not_found", "message": message } });
            (StatusCode::NOT_FOUND, axum::Json(body)).into_response()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_refers_only_to_embedded_assets() {
        for cap in INDEX_HTML.split("/assets/").skip(1) {
            let name: String = cap.chars().take_while(|c| *c != '"' && *c != '?').collect();
            assert!(asset(&name).is_some(), "index.html refers to /assets/{name}, which is not embedded");
        }
        assert!(!INDEX_HTML.contains("http://") && !INDEX_HTML.contains("https://"));
        // The SVG namespace is a name, not a place the page goes to.
        let js = format!("{APP_JS}{WORKBENCH_JS}").replace("http://www.w3.org/2000/svg", "");
        assert!(
            !js.contains("http://") && !js.contains("https://"),
            "the script fetches only from this gateway"
        );
    }

    #[test]
    fn unknown_assets_are_json_404s() {
        assert!(asset("../Cargo.toml").is_none());
        assert!(asset("").is_none());
    }

    async fn get(app: &Router, path: &str) -> (StatusCode, String, String) {
        use http_body_util::BodyExt;
        use tower::ServiceExt;
        let req = axum::http::Request::get(path).body(axum::body::Body::empty()).unwrap();
        let r = app.clone().oneshot(req).await.unwrap();
        let status = r.status();
        let ct = r
            .headers()
            .get(header::CONTENT_TYPE)
            .map(|v| v.to_str().unwrap().to_string())
            .unwrap_or_default();
        let body = r.into_body().collect().await.unwrap().to_bytes();
        (status, ct, String::from_utf8_lossy(&body).into_owned())
    }

    /// The page and its assets are served by the gateway's router without a token, even where
    /// reads need one: the page itself holds nothing secret and asks for the token.
    #[tokio::test(start_paused = true)]
    async fn the_router_serves_the_page_without_a_token() {
        let mut cfg = crate::GatewayConfig::demo();
        cfg.http.anonymous_read = false;
        cfg.store = None;
        let gw = Gateway::start(cfg, None).unwrap();
        let app = crate::http::router(gw);
        let (status, ct, body) = get(&app, "/").await;
        assert_eq!(status, StatusCode::OK);
        assert!(ct.starts_with("text/html"), "{ct}");
        assert!(body.contains("/assets/app.js") && body.contains("tile-template"));
        for (path, want) in [
            ("/assets/app.js", "text/javascript"),
            ("/assets/workbench.js", "text/javascript"),
            ("/assets/style.css", "text/css"),
            ("/assets/favicon.svg", "image/svg+xml"),
        ] {
            let (status, ct, body) = get(&app, path).await;
            assert_eq!(status, StatusCode::OK, "{path}");
            assert!(ct.starts_with(want), "{path}: {ct}");
            assert!(!body.is_empty());
        }
        let (status, ct, body) = get(&app, "/assets/missing.js").await;
        assert_eq!(status, StatusCode::NOT_FOUND);
        assert!(ct.starts_with("application/json"), "{ct}");
        let v: serde_json::Value = serde_json::from_str(&body).unwrap();
        assert_eq!(v["error"]["kind"], "not_found");
        assert!(v["error"]["message"].as_str().unwrap().contains("missing.js"));
    }
}
