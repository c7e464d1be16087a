//! Operator verdicts on the page's flags and the model's heat maps. `POST
//! /api/layers/{layer}/verdicts` records "confirm" or "false alarm" on one flag of that layer
//! (who and when) in `<build>/verdicts.jsonl`, which `layerwise learn train --data BUILD` learns
//! from; `GET` the same path lists the layer's verdicts; `GET
//! /api/layers/{layer}/{view}/heatmap.png` is the model's per-tile defect probability of a view.
//! Behind the page's token like every route (the router's `authorize`).

use super::state::PageState;
use crate::build_dir::inspection::InspectionLog;
use crate::learn::verdicts::{latest, FlagRef, Judgement, Verdict, VerdictLog, VERDICTS};
use crate::shot::{Shot, MAX_LAYER};
use axum::extract::{Path, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;
use serde_json::json;
use std::sync::{Arc, Mutex};

/// One verdict at a time is appended.
static APPEND: Mutex<()> = Mutex::new(());
const MAX_WHO: usize = 64;

fn answer(status: StatusCode, message: impl Into<String>) -> Response {
    (status, Json(json!({ "error": message.into() }))).into_response()
}

fn layer_of(text: &str) -> Option<u32> {
    let digits = text.len() <= 5 && text.bytes().all(|b| b.is_ascii_digit());
    let n: u32 = text.parse().ok()?;
    (digits && (1..=MAX_LAYER).contains(&n)).then_some(n)
}

fn not_a_layer(text: &str) -> Response {
    answer(
        StatusCode::BAD_REQUEST,
        format!(
            "'{}' is not a layer number (1 to {MAX_LAYER})",
            text.escape_debug()
        ),
    )
}

fn view_ok(view: &str) -> bool {
    Shot::from_stem(&format!("L00001_{view}")).is_some_and(|s| s.view().to_string() == view)
}

/// What the page sends.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct VerdictRequest {
    view: String,
    flag: FlagRef,
    verdict: Judgement,
    #[serde(default)]
    who: Option<String>,
}

/// Records a verdict on a flag the layer has.
pub(crate) async fn post(
    State(shared): State<Arc<PageState>>,
    Path(layer): Path<String>,
    Json(request): Json<VerdictRequest>,
) -> Response {
    let Some(n) = layer_of(&layer) else {
        return not_a_layer(&layer);
    };
    if !view_ok(&request.view) {
        return answer(
            StatusCode::BAD_REQUEST,
            format!(
                "'{}' is not a view, e.g. post_top",
                request.view.escape_debug()
            ),
        );
    }
    let who = request
        .who
        .as_deref()
        .map(str::trim)
        .unwrap_or("")
        .to_string();
    let who = if who.is_empty() {
        "operator".to_string()
    } else {
        who
    };
    if who.chars().count() > MAX_WHO || who.chars().any(char::is_control) {
        return answer(
            StatusCode::BAD_REQUEST,
            format!("who: at most {MAX_WHO} printable characters"),
        );
    }
    let dir = shared.dir.clone();
    let verdict = Verdict {
        layer: n,
        view: request.view,
        flag: request.flag,
        verdict: request.verdict,
        who,
        at: chrono::Utc::now(),
    };
    let done = tokio::task::spawn_blocking(move || -> Result<Verdict, (StatusCode, String)> {
        let records =
            InspectionLog::read(&dir.join(crate::build_dir::INSPECTION)).map_err(|e| {
                (
                    StatusCode::NOT_FOUND,
                    format!("no inspection records: {}", crate::logging::chain(&e)),
                )
            })?;
        let known = records
            .iter()
            .filter(|r| r.layer == verdict.layer)
            .flat_map(|r| &r.flags)
            .any(|f| {
                f.view == verdict.view
                    && f.kind.name() == verdict.flag.kind
                    && f.class == verdict.flag.class
                    && f.bbox_mm
                        .iter()
                        .zip(&verdict.flag.bbox_mm)
                        .all(|(a, b)| (a - b).abs() < 1e-6)
            });
        if !known {
            return Err((
                StatusCode::NOT_FOUND,
                format!(
                    "layer {} has no {} flag on {} at {:?}",
                    verdict.layer, verdict.flag.kind, verdict.view, verdict.flag.bbox_mm
                ),
            ));
        }
        let _one = APPEND.lock().unwrap_or_else(|e| e.into_inner());
        let mut log = VerdictLog::append_only(&dir.join(VERDICTS))
            .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, crate::logging::chain(&e)))?;
        log.append(&verdict)
            .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, crate::logging::chain(&e)))?;
        Ok(verdict)
    })
    .await;
    match done {
        Ok(Ok(v)) => Json(v).into_response(),
        Ok(Err((status, message))) => answer(status, message),
        Err(e) => answer(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("request failed: {e}"),
        ),
    }
}

/// The layer's verdicts (the last one per flag).
pub(crate) async fn list(
    State(shared): State<Arc<PageState>>,
    Path(layer): Path<String>,
) -> Response {
    let Some(n) = layer_of(&layer) else {
        return not_a_layer(&layer);
    };
    let dir = shared.dir.clone();
    let read = tokio::task::spawn_blocking(move || latest(&dir)).await;
    match read {
        Ok(Ok(all)) => {
            let of_layer: Vec<Verdict> = all.into_iter().filter(|v| v.layer == n).collect();
            Json(json!({ "layer": n, "verdicts": of_layer })).into_response()
        }
        Ok(Err(e)) => answer(StatusCode::INTERNAL_SERVER_ERROR, crate::logging::chain(&e)),
        Err(e) => answer(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("request failed: {e}"),
        ),
    }
}

/// The model's heat map of a view of a layer (one grey pixel per tile).
pub(crate) async fn heatmap(
    State(shared): State<Arc<PageState>>,
    Path((layer, view)): Path<(String, String)>,
) -> Response {
    let (Some(n), true) = (layer_of(&layer), view_ok(&view)) else {
        return answer(
            StatusCode::BAD_REQUEST,
            "a layer number and a view, e.g. /api/layers/12/pre_top/heatmap.png",
        );
    };
    // Through the page's one way to the disk, as every file it serves: a link, a FIFO or a
    // device planted as a heat map is refused, never followed, waited on or read without end.
    let dir = shared.dir.clone();
    let name = format!("L{n:05}.png");
    let folder = view.clone();
    let read = move || {
        let parts = [
            crate::learn::live::HEATMAP_DIR,
            folder.as_str(),
            name.as_str(),
        ];
        super::files::read(&dir, &parts, super::files::FileKind::HeatMap)
    };
    match tokio::task::spawn_blocking(read).await {
        Ok(Ok(bytes)) => (
            [
                (header::CONTENT_TYPE, "image/png"),
                (header::CACHE_CONTROL, "no-cache"),
            ],
            bytes,
        )
            .into_response(),
        Ok(Err(e)) if e.is_not_found() => answer(
            StatusCode::NOT_FOUND,
            format!("no heat map of layer {n} {view} (no [inspection.model], or not yet)"),
        ),
        Ok(Err(e)) => answer(e.status(), crate::logging::chain(&e)),
        Err(e) => answer(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("request failed: {e}"),
        ),
    }
}
