//! The alarm on the page: its history (`GET /api/alarm`) and the operator's acknowledgement
//! (`POST /api/alarm/ack`, behind the page's token like every route), recorded exactly as
//! `layerwise alarm ack` records it; every open page is told at once.

use super::state::PageState;
use crate::build_dir::alarm::{self, AckError};
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;
use serde_json::{json, Value};
use std::sync::Arc;

/// An error answer: its status and what to do, as JSON (as the other routes answer).
pub(super) struct AlarmError(StatusCode, String);

impl IntoResponse for AlarmError {
    fn into_response(self) -> Response {
        (self.0, Json(json!({ "error": self.1 }))).into_response()
    }
}

async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, AlarmError> {
    tokio::task::spawn_blocking(f).await.map_err(|e| {
        AlarmError(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("request failed: {e}"),
        )
    })
}

/// What the page sends: who acknowledges, and what was checked or decided.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AckRequest {
    by: String,
    #[serde(default)]
    note: Option<String>,
    /// The layer whose raise the page showed: refused (409) when the alarm raised now is
    /// another's (a page that had not yet shown the new raise).
    #[serde(default)]
    layer: Option<u32>,
    /// When that raise was raised (the status's `alarm.at`): a raise of the same layer again is
    /// another.
    #[serde(default)]
    raised_at: Option<chrono::DateTime<chrono::Utc>>,
}

/// The alarm's history, oldest first, and where it leaves the alarm.
pub(super) async fn history(
    State(shared): State<Arc<PageState>>,
) -> Result<Json<Value>, AlarmError> {
    let dir = shared.dir.clone();
    let (events, state) = blocking(move || (alarm::history(&dir), alarm::state(&dir))).await?;
    let events = events
        .map_err(|e| AlarmError(StatusCode::INTERNAL_SERVER_ERROR, crate::logging::chain(&e)))?;
    Ok(Json(json!({ "events": events, "state": state })))
}

/// Records the acknowledgement, remakes the status and tells every open page.
pub(super) async fn acknowledge(
    State(shared): State<Arc<PageState>>,
    Json(request): Json<AckRequest>,
) -> Result<Json<Value>, AlarmError> {
    let s = shared.clone();
    let state = blocking(move || {
        let state = alarm::acknowledge(
            &s.dir,
            &request.by,
            request.note.as_deref(),
            chrono::Utc::now(),
            request.layer.map(|layer| alarm::SeenRaise {
                layer,
                at: request.raised_at,
            }),
        );
        s.refresh_status();
        state
    })
    .await?
    .map_err(|e| {
        let status = match e {
            AckError::NotRaised { .. } | AckError::Another { .. } => StatusCode::CONFLICT,
            AckError::Invalid { .. } => StatusCode::BAD_REQUEST,
            AckError::NotABuild(_) => StatusCode::NOT_FOUND,
            AckError::Log(_) => StatusCode::INTERNAL_SERVER_ERROR,
            AckError::Locked(_) => StatusCode::SERVICE_UNAVAILABLE,
        };
        AlarmError(status, crate::logging::chain(&e))
    })?;
    shared.updates.send_modify(|v| *v += 1);
    Ok(Json(json!({ "state": state, "shown": state.to_string() })))
}
