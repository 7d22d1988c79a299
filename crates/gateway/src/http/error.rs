//! JSON errors: every 4xx/5xx answer of the API is
//! `{"error": {"kind": "<snake_case>", "message": "<one line>"}}`.

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::json;

use crate::core::CommandError;
use crate::text::cut;

/// An error answer: status, kind and a one-line message naming the problem.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ApiError {
    /// The HTTP status.
    pub status: StatusCode,
    /// A short snake_case kind (`unknown_drive`, `bad_json`, ...).
    pub kind: &'static str,
    /// One line saying what was wrong.
    pub message: String,
}

impl ApiError {
    /// An error with `status`, `kind` and `message` (newlines are folded into one line, and a
    /// message over [`crate::core::MAX_MESSAGE_CHARS`] characters is cut: it quotes a user's
    /// value).
    pub fn new(status: StatusCode, kind: &'static str, message: impl Into<String>) -> Self {
        let message: String = message.into();
        let message = if message.contains(['\n', '\r']) {
            message.split(['\n', '\r']).map(str::trim).filter(|s| !s.is_empty()).collect::<Vec<_>>().join(" ")
        } else {
            message
        };
        let message = crate::text::shown_max(&message, crate::core::MAX_MESSAGE_CHARS);
        ApiError { status, kind, message }
    }

    /// 400 `bad_json`: the body is not JSON.
    pub fn bad_json(message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::BAD_REQUEST, "bad_json", message)
    }

    /// 400 `bad_request`: a query string or path that cannot be understood.
    pub fn bad_request(message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::BAD_REQUEST, "bad_request", message)
    }

    /// 422 `invalid`: well-formed but not acceptable; nothing was sent.
    pub fn invalid(message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "invalid", message)
    }

    /// 404 `not_found`: no such path.
    pub fn not_found(path: &str) -> Self {
        let (shown, more) = cut(path, 200);
        ApiError::new(
            StatusCode::NOT_FOUND,
            "not_found",
            format!("no route {shown}{more}: GET /api/openapi.json lists them"),
        )
    }

    /// 503 `no_store`: the gateway keeps no events or trends.
    pub fn no_store() -> Self {
        ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "no_store",
            "this gateway keeps no events or trends (it was started with --no-store, or its \
             configuration says [store] disabled = true): give it a [store] path and start it without either",
        )
    }

    /// 500 `internal`: a defect in the gateway.
    pub fn internal(message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", message)
    }

    /// The error a status alone implies, for answers made by the framework (405, 413, ...).
    pub fn from_status(status: StatusCode, detail: &str) -> Self {
        let detail = detail.trim();
        let (kind, default) = match status {
            StatusCode::NOT_FOUND => ("not_found", "no such route: GET /api/openapi.json lists them"),
            StatusCode::METHOD_NOT_ALLOWED => (
                "method_not_allowed",
                "this route does not take that method: GET /api/openapi.json lists them",
            ),
            StatusCode::PAYLOAD_TOO_LARGE => ("too_large", "the request body is larger than [http] max_body"),
            StatusCode::UNAUTHORIZED => ("unauthorized", "send Authorization: Bearer <token>"),
            StatusCode::FORBIDDEN => ("forbidden", "this token may not do that"),
            StatusCode::UNSUPPORTED_MEDIA_TYPE => {
                ("bad_request", "unsupported content type: send application/json")
            }
            s if s.is_server_error() => ("internal", "the gateway failed to answer"),
            _ => ("bad_request", "the request cannot be understood"),
        };
        let message = if detail.is_empty() { default.to_string() } else { detail.to_string() };
        ApiError::new(status, kind, message)
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {}: {}", self.status.as_u16(), self.kind, self.message)
    }
}

/// The HTTP status that says what happened to a command or parameter read.
pub fn status_of(e: &CommandError) -> StatusCode {
    match e {
        CommandError::UnknownDrive(_) | CommandError::UnknownBus(_) => StatusCode::NOT_FOUND,
        CommandError::Locked(_) => StatusCode::LOCKED,
        CommandError::Invalid(_) | CommandError::Unsupported(_) => StatusCode::UNPROCESSABLE_ENTITY,
        CommandError::Refused { .. } => StatusCode::CONFLICT,
        CommandError::NoAnswer(_) => StatusCode::GATEWAY_TIMEOUT,
        CommandError::LinkDown(_) => StatusCode::SERVICE_UNAVAILABLE,
        CommandError::Protocol(_) => StatusCode::BAD_GATEWAY,
        CommandError::Busy(_) => StatusCode::TOO_MANY_REQUESTS,
        CommandError::NotRecorded(_) | CommandError::Standby(_) => StatusCode::SERVICE_UNAVAILABLE,
    }
}

impl From<CommandError> for ApiError {
    fn from(e: CommandError) -> Self {
        let message = match e {
            // Where an HTTP client finds the names.
            CommandError::UnknownDrive(_) => format!("{e}: GET /api/drives lists them"),
            CommandError::UnknownBus(_) => format!("{e}: GET /api/buses lists them"),
            _ => e.to_string(),
        };
        ApiError::new(status_of(&e), e.kind(), message)
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = json!({ "error": { "kind": self.kind, "message": self.message } });
        let mut r = (self.status, Json(body)).into_response();
        if self.status == StatusCode::UNAUTHORIZED {
            r.headers_mut().insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        }
        if self.status == StatusCode::TOO_MANY_REQUESTS {
            // A busy bus frees within a few transactions.
            r.headers_mut().insert(header::RETRY_AFTER, HeaderValue::from_static("1"));
        }
        r
    }
}
