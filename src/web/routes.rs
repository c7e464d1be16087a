//! The page's routes: static files, JSON, pictures, originals, vectors and the event stream.
//! Requests name layers and views only; both are checked before anything reaches the disk.

use super::clients::{self, Client};
use super::files::{BuildFile, FileError, FileKind};
use super::preview::{self, Kind, PreviewError, Region};
use super::state::PageState;
use super::timeline::LayerState;
use crate::build_dir::RAW_DIR;
use crate::logging::chain;
use crate::shot::{Shot, View, MAX_LAYER};
use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Path, Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Extension, Json, Router};
use serde::Deserialize;
use serde_json::json;
use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

const INDEX_HTML: &str = include_str!("page/index.html");
const APP_JS: &str = include_str!("page/app.js");
const STYLE_CSS: &str = include_str!("page/style.css");
const CALIBRATE_HTML: &str = include_str!("page/calibrate.html");

pub(crate) fn router(shared: Arc<PageState>) -> Router {
    let limits = shared.clients.limits();
    Router::new()
        .route(
            "/",
            get(|| async { page(INDEX_HTML, "text/html; charset=utf-8") }),
        )
        .route(
            "/app.js",
            get(|| async { page(APP_JS, "text/javascript; charset=utf-8") }),
        )
        .route(
            "/style.css",
            get(|| async { page(STYLE_CSS, "text/css; charset=utf-8") }),
        )
        .route(
            "/calibrate",
            get(|| async { page(CALIBRATE_HTML, "text/html; charset=utf-8") }),
        )
        .route("/api/calibration", axum::routing::post(calibrate))
        .route("/api/calibration/{stamp}/overlay.png", get(overlay))
        .route("/api/status", get(status))
        .route("/api/alarm", get(super::alarm::history))
        .route(
            "/api/alarm/ack",
            axum::routing::post(super::alarm::acknowledge),
        )
        .route("/api/trends", get(super::trends::get))
        .route("/api/layers", get(layers))
        .route("/api/layers/{layer}", get(layer))
        .route("/api/layers/{layer}/vectors.svg", get(vectors))
        .route("/api/layers/{layer}/{view}/picture.jpg", get(picture))
        .route("/api/layers/{layer}/{view}/original", get(original))
        .route(
            "/api/layers/{layer}/verdicts",
            get(super::verdicts::list).post(super::verdicts::post),
        )
        .route(
            "/api/layers/{layer}/{view}/heatmap.png",
            get(super::verdicts::heatmap),
        )
        .route("/api/events", get(events))
        .route("/metrics", get(metrics))
        // Bodies are received (bounded in bytes and time) only once the token was shown.
        .layer(middleware::from_fn_with_state(limits, clients::receive))
        .layer(middleware::from_fn_with_state(shared.clone(), authorize))
        .layer(middleware::from_fn(clients::track))
        .layer(DefaultBodyLimit::max(clients::MAX_BODY_BYTES))
        .with_state(shared)
}

/// Prometheus metrics, when on (`[metrics] enabled`, `serve --metrics`; docs/metrics.md).
async fn metrics(State(shared): State<Arc<PageState>>) -> Response {
    let status = shared
        .status
        .read()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    match crate::plant::metrics::render(status, chrono::Utc::now()) {
        Some(text) => (
            [(header::CONTENT_TYPE, crate::plant::metrics::CONTENT_TYPE)],
            text,
        )
            .into_response(),
        None => not_found("metrics are off: set [metrics] enabled = true (serve: --metrics)")
            .into_response(),
    }
}

fn page(text: &'static str, kind: &'static str) -> Response {
    ([(header::CONTENT_TYPE, kind)], text).into_response()
}

/// An error answer: its status and what to do, as JSON.
pub(crate) struct ApiError(StatusCode, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.0, Json(json!({ "error": self.1 }))).into_response()
    }
}

fn bad(message: impl Into<String>) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, message.into())
}

fn not_found(message: impl Into<String>) -> ApiError {
    ApiError(StatusCode::NOT_FOUND, message.into())
}

/// A layer number as typed by a user: 1 to 99999, digits only.
pub fn parse_layer(text: &str) -> Result<u32, ApiError> {
    let digits = !text.is_empty() && text.len() <= 5 && text.bytes().all(|b| b.is_ascii_digit());
    match text.parse::<u32>() {
        Ok(n) if digits && (1..=MAX_LAYER).contains(&n) => Ok(n),
        _ => Err(bad(format!(
            "'{}' is not a layer number (1 to {MAX_LAYER})",
            text.escape_debug()
        ))),
    }
}

/// A view name: `{phase}_{light}` exactly as the build directory spells it.
pub fn parse_view(text: &str) -> Result<View, ApiError> {
    let view = text.split_once('_').and_then(|(phase, light)| {
        Some(View {
            phase: phase.parse().ok()?,
            light: light.parse().ok()?,
        })
    });
    match view {
        Some(v) if v.to_string() == text => Ok(v),
        _ => Err(bad(format!(
            "'{}' is not a view: pre or post, then front, side or top, e.g. post_top",
            text.escape_debug()
        ))),
    }
}

/// Bearer token from the Authorization header, or the cookie the page sets from `?token=`.
async fn authorize(State(shared): State<Arc<PageState>>, request: Request, next: Next) -> Response {
    let Some(token) = &shared.token else {
        // Without a token the page listens on loopback only (web.token_file is required beyond
        // it), so its browsers name it by a loopback address or `localhost`. Another name is a
        // site whose name was made to resolve to 127.0.0.1 (DNS rebinding): its script would
        // read the build and acknowledge the alarm as the operator's page does.
        if !super::host::own_host(request.headers(), &shared.config.allowed_hosts) {
            return ApiError(
                StatusCode::FORBIDDEN,
                "without web.token_file the page answers only to 127.0.0.1, [::1], localhost and \
                 web.allowed_hosts (a page under another name is refused: DNS rebinding); add \
                 the name a reverse proxy sends to web.allowed_hosts, or set web.token_file"
                    .into(),
            )
            .into_response();
        }
        return next.run(request).await;
    };
    let headers = request.headers();
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "));
    let cookie = headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|c| c.trim().strip_prefix("layerwise_token="))
        .next();
    let query = request
        .uri()
        .query()
        .into_iter()
        .flat_map(|q| q.split('&'))
        .find_map(|kv| kv.strip_prefix("token="));
    let equal = |given: Option<&str>| given.is_some_and(|g| same(g.as_bytes(), token.as_bytes()));
    if equal(bearer) || equal(cookie) {
        return next.run(request).await;
    }
    if equal(query) {
        let mut response = next.run(request).await;
        let cookie = format!("layerwise_token={token}; HttpOnly; SameSite=Strict; Path=/");
        if let Ok(value) = HeaderValue::from_str(&cookie) {
            response.headers_mut().insert(header::SET_COOKIE, value);
        }
        return response;
    }
    ApiError(
        StatusCode::UNAUTHORIZED,
        "this page needs the token of web.token_file: open it as /?token=… or send Authorization: Bearer …".into(),
    )
    .into_response()
}

/// Compares in time independent of where the first difference is.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

async fn status(State(shared): State<Arc<PageState>>) -> Result<Response, ApiError> {
    let cached = shared
        .status
        .read()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    let report = match cached {
        Some(r) => Some(r),
        None => blocking(move || shared.refresh_status()).await?,
    };
    report.map(|r| Json(&*r).into_response()).ok_or_else(|| {
        not_found("no build here yet (no journal.jsonl): the daemon has not started it")
    })
}

/// The configured views, else those the journal shows.
fn views(shared: &PageState) -> Vec<String> {
    match shared.info() {
        Some(info) => info.views.iter().map(ToString::to_string).collect(),
        None => {
            let timeline = shared.timeline.read().unwrap_or_else(|e| e.into_inner());
            let mut seen: Vec<String> = timeline
                .layers
                .values()
                .flat_map(|l| l.views.keys().cloned())
                .collect();
            seen.sort();
            seen.dedup();
            seen
        }
    }
}

#[derive(Deserialize)]
struct LayersQuery {
    from: Option<u32>,
}

async fn layers(
    State(shared): State<Arc<PageState>>,
    Query(q): Query<LayersQuery>,
) -> Json<serde_json::Value> {
    let views = views(&shared);
    let info = shared.info();
    let timeline = shared.timeline.read().unwrap_or_else(|e| e.into_inner());
    let from = q.from.unwrap_or(0);
    let layers: Vec<_> = timeline
        .layers
        .range(from..)
        .map(|(_, l)| l.summary())
        .collect();
    let expected = shared
        .status
        .read()
        .unwrap_or_else(|e| e.into_inner())
        .as_ref()
        .and_then(|s| s.layers_expected);
    Json(json!({
        "views": views,
        "newest": timeline.newest_with_frames(),
        "complete": timeline.newest_complete(views.len()),
        "layers_expected": expected,
        "rectified": info.as_ref().is_some_and(|i| i.rectification.is_some()),
        "vectors": info.as_ref().is_some_and(|i| i.vectors_file.is_some()),
        "grid": info.as_ref().map(|i| i.grid),
        "calibration_page": shared.config.calibration_page,
        // A crop larger than this many pixels a side is scaled down (web.preview_px): the
        // page's zoom keeps its crops smaller, at full resolution.
        "crop_px": shared.config.preview_px,
        "layers": layers,
    }))
}

async fn layer(
    State(shared): State<Arc<PageState>>,
    Path(layer): Path<String>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let n = parse_layer(&layer)?;
    let state = layer_state(&shared, n)?;
    let grid = shared.info().map(|i| i.grid);
    let inspection = inspection_flags(&state, grid.as_ref(), &views(&shared));
    let bed = {
        let timeline = shared.timeline.read().unwrap_or_else(|e| e.into_inner());
        super::bed::layer_bed(&timeline, n, grid.as_ref())
    };
    let pictures: BTreeMap<String, serde_json::Value> = state
        .views
        .iter()
        .filter(|(_, v)| v.file.is_some())
        .map(|(view, _)| {
            let base = format!("/api/layers/{n}/{view}");
            (
                view.clone(),
                json!({
                    "rectified": format!("{base}/picture.jpg?kind=rectified"),
                    "raw": format!("{base}/picture.jpg?kind=raw"),
                    "original": format!("{base}/original"),
                }),
            )
        })
        .collect();
    Ok(Json(json!({
        "layer": n,
        "summary": state.summary(),
        "views": state.views,
        "signals": state.signals,
        "flags": state.flags,
        "inspection": inspection,
        "bed": bed,
        "pictures": pictures,
        "vectors": format!("/api/layers/{n}/vectors.svg"),
    })))
}

/// A layer's inspection flags as the page draws them: each record with `box`, its bbox on the
/// series grid as fractions `{x, y, w, h}` of the rectified picture (the grid's whole extent at
/// any preview size, as vectors.svg's viewBox; null before the build's configuration snapshot
/// exists), and `draw_on`, the views it is outlined over: its own view, and for a plate-wide
/// flag (no part) every view of its phase.
fn inspection_flags(
    state: &LayerState,
    grid: Option<&crate::geometry::Grid>,
    views: &[String],
) -> Vec<serde_json::Value> {
    state
        .inspection
        .iter()
        .map(|flag| {
            let picture_box = grid.map(|g| {
                let (cols, rows) = (g.columns().max(1) as f64, g.rows().max(1) as f64);
                let [c0, r0, c1, r1] = flag.bbox_px.map(f64::from);
                let x = (c0 / cols).min(1.0);
                let y = (r0 / rows).min(1.0);
                json!({
                    "x": x,
                    "y": y,
                    "w": ((c1 + 1.0) / cols).min(1.0) - x,
                    "h": ((r1 + 1.0) / rows).min(1.0) - y,
                })
            });
            let phase = flag.view.split('_').next().unwrap_or_default();
            let draw_on: Vec<&String> = match flag.part {
                Some(_) => views.iter().filter(|v| **v == flag.view).collect(),
                None => views
                    .iter()
                    .filter(|v| v.split('_').next() == Some(phase))
                    .collect(),
            };
            let mut value = serde_json::to_value(flag).unwrap_or_default();
            value["box"] = picture_box.unwrap_or_default();
            value["draw_on"] = json!(draw_on);
            value
        })
        .collect()
}

fn layer_state(shared: &PageState, n: u32) -> Result<LayerState, ApiError> {
    let timeline = shared.timeline.read().unwrap_or_else(|e| e.into_inner());
    timeline
        .layers
        .get(&n)
        .cloned()
        .ok_or_else(|| not_found(format!("layer {n} has no frames or signals (yet)")))
}

/// The stored original of a view of a layer, from the journal, checked to be
/// `raw/L{layer}_{view}.{ext}` in the build directory (opened only through [`super::files`]).
fn original_path(shared: &PageState, n: u32, view: View) -> Result<BuildFile, ApiError> {
    let state = layer_state(shared, n)?;
    let file = state
        .view(view)
        .and_then(|v| v.file.clone())
        .ok_or_else(|| not_found(format!("layer {n} has no {view} frame")))?;
    let stem = Shot {
        layer: n,
        phase: view.phase,
        light: view.light,
    }
    .stem();
    let ext = file
        .strip_prefix(&format!("{RAW_DIR}/{stem}."))
        .filter(|e| !e.is_empty() && e.len() <= 8 && e.bytes().all(|b| b.is_ascii_alphanumeric()))
        .ok_or_else(|| {
            not_found(format!(
                "the journal names an unexpected file for layer {n} {view}"
            ))
        })?;
    Ok(BuildFile::new(
        &shared.dir,
        &[RAW_DIR, &format!("{stem}.{ext}")],
    ))
}

/// The answer to a file the page will not read ([`FileError::status`]).
fn file_error(e: &FileError) -> ApiError {
    ApiError(e.status(), chain(e))
}

#[derive(Deserialize)]
struct PictureQuery {
    kind: Option<String>,
    x: Option<f64>,
    y: Option<f64>,
    w: Option<f64>,
    h: Option<f64>,
}

async fn picture(
    State(shared): State<Arc<PageState>>,
    Path((layer, view)): Path<(String, String)>,
    Query(q): Query<PictureQuery>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let (n, view) = (parse_layer(&layer)?, parse_view(&view)?);
    let kind: Kind = q
        .kind
        .as_deref()
        .unwrap_or("rectified")
        .parse()
        .map_err(|e: preview::UnknownKind| bad(e.to_string()))?;
    let region = match (q.x, q.y, q.w, q.h) {
        (None, None, None, None) => Region::WHOLE,
        (Some(x), Some(y), Some(w), Some(h)) => {
            Region::checked(x, y, w, h).map_err(|e| bad(e.to_string()))?
        }
        _ => return Err(bad("a crop needs all of x, y, w and h")),
    };
    let path = original_path(&shared, n, view)?;
    let tag = {
        let (s, original) = (shared.clone(), path.path());
        blocking(move || {
            let made_with = s.info().map(|i| i.made_with.clone()).unwrap_or_default();
            let max_px = s.config.preview_px;
            preview::validator(&original, (kind, region), &made_with, max_px)
        })
        .await?
    };
    let tag = tag.and_then(|t| HeaderValue::from_str(&t).ok());
    let cache = (
        header::CACHE_CONTROL,
        HeaderValue::from_static("private, no-cache"),
    );
    if let Some(tag) = &tag {
        if headers.get(header::IF_NONE_MATCH) == Some(tag) {
            let etag = (header::ETAG, tag.clone());
            return Ok((StatusCode::NOT_MODIFIED, [cache, etag]).into_response());
        }
    }
    let jpeg = make_picture(&shared, path, kind, region).await?;
    let mut answer = (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static("image/jpeg")),
            cache,
        ],
        jpeg,
    )
        .into_response();
    if let Some(tag) = tag {
        answer.headers_mut().insert(header::ETAG, tag);
    }
    Ok(answer)
}

/// The picture from the cache, else made on the blocking pool, one at a time.
async fn make_picture(
    shared: &Arc<PageState>,
    path: BuildFile,
    kind: Kind,
    region: Region,
) -> Result<Bytes, ApiError> {
    if let Some(hit) = shared.pictures.cached(&path, kind, region) {
        return Ok(hit);
    }
    let _turn = shared
        .encode
        .acquire()
        .await
        .map_err(|_| ApiError(StatusCode::SERVICE_UNAVAILABLE, "shutting down".into()))?;
    let s = shared.clone();
    blocking(move || {
        let info = s.info();
        let rectification = info.as_ref().and_then(|i| i.rectification.as_ref());
        s.pictures.picture(&path, kind, region, rectification)
    })
    .await?
    .map_err(|e| match e {
        PreviewError::NoCalibration => not_found(e.to_string()),
        PreviewError::TooSmall => bad(e.to_string()),
        PreviewError::File(e) => file_error(&e),
        // The request was understood; the frame it names is not a picture.
        PreviewError::Decode { .. } => ApiError(StatusCode::UNPROCESSABLE_ENTITY, chain(&e)),
        other => ApiError(StatusCode::INTERNAL_SERVER_ERROR, chain(&other)),
    })
}

/// Makes the previews of the newest layer before a page asks for them.
pub(crate) async fn prepare_newest(shared: &Arc<PageState>) {
    let newest = {
        let timeline = shared.timeline.read().unwrap_or_else(|e| e.into_inner());
        timeline
            .newest_with_frames()
            .and_then(|n| timeline.layers.get(&n).cloned())
    };
    let Some(state) = newest else { return };
    let kind = match shared.info() {
        Some(info) if info.rectification.is_some() => Kind::Rectified,
        _ => Kind::Raw,
    };
    for view in state.views.keys().filter_map(|v| parse_view(v).ok()) {
        if let Ok(path) = original_path(shared, state.layer, view) {
            let _ = make_picture(shared, path, kind, Region::WHOLE).await;
        }
    }
}

async fn original(
    State(shared): State<Arc<PageState>>,
    Path((layer, view)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let (n, view) = (parse_layer(&layer)?, parse_view(&view)?);
    let file = original_path(&shared, n, view)?;
    let name = file.file_name().to_string();
    let kind = match name.rsplit_once('.').map(|(_, e)| e.to_ascii_lowercase()) {
        Some(e) if e == "jpg" || e == "jpeg" => "image/jpeg",
        Some(e) if e == "png" => "image/png",
        Some(e) if e == "tif" || e == "tiff" => "image/tiff",
        _ => "application/octet-stream",
    };
    let opened = blocking(move || file.open(FileKind::Frame))
        .await?
        .map_err(|e| file_error(&e))?;
    let disposition = format!("inline; filename=\"{name}\"");
    let mut headers = HeaderMap::new();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(kind));
    headers.insert(header::CONTENT_LENGTH, HeaderValue::from(opened.size));
    if let Ok(v) = HeaderValue::from_str(&disposition) {
        headers.insert(header::CONTENT_DISPOSITION, v);
    }
    Ok((headers, super::files::stream(opened)).into_response())
}

/// Most vector segments drawn over a picture; beyond it hatches are thinned out evenly.
const MAX_SEGMENTS: usize = 40_000;

async fn vectors(
    State(shared): State<Arc<PageState>>,
    Path(layer): Path<String>,
) -> Result<Response, ApiError> {
    let n = parse_layer(&layer)?;
    let info = shared
        .info()
        .ok_or_else(|| not_found("the build has no configuration snapshot yet"))?;
    let svg = blocking(move || -> Result<String, ApiError> {
        let index = info
            .vectors()
            .ok_or_else(|| not_found("the build has no vector file (build.vectors)"))?
            .map_err(|e| not_found(format!("the build's vector file: {}", chain(e.as_ref()))))?;
        let position = index
            .layer_map(info.numbering)
            .position(n)
            .ok_or_else(|| not_found(format!("the vector file has no layer {n}")))?;
        let layer = index
            .read_layer(position)
            .map_err(|e| not_found(chain(&e)))?;
        Ok(layer_svg(&layer, &info.grid))
    })
    .await??;
    Ok(([(header::CONTENT_TYPE, "image/svg+xml")], svg).into_response())
}

/// A layer's contours and hatches in the pixels of `grid` (viewBox = the whole grid).
pub fn layer_svg(layer: &crate::vectors::Layer, grid: &crate::geometry::Grid) -> String {
    use std::fmt::Write;
    let at = |x: f64, y: f64| {
        let (row, col) = grid.pixel_of(x, y);
        (col + 0.5, row + 0.5)
    };
    let mut contours = String::new();
    for polyline in &layer.polylines {
        for (i, p) in polyline.points.iter().enumerate() {
            let (x, y) = at(p[0], p[1]);
            let _ = write!(contours, "{}{x:.1} {y:.1} ", if i == 0 { 'M' } else { 'L' });
        }
    }
    let total: usize = layer.hatches.iter().map(|h| h.segments.len()).sum();
    let step = total.div_ceil(MAX_SEGMENTS).max(1);
    let mut hatches = String::new();
    for s in layer.hatches.iter().flat_map(|h| &h.segments).step_by(step) {
        let (x0, y0) = at(s[0], s[1]);
        let (x1, y1) = at(s[2], s[3]);
        let _ = write!(hatches, "M{x0:.1} {y0:.1} L{x1:.1} {y1:.1} ");
    }
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {} {}\" preserveAspectRatio=\"none\">\
         <path class=\"hatch\" d=\"{hatches}\" fill=\"none\" stroke=\"#29b6f6\" stroke-opacity=\"0.5\" vector-effect=\"non-scaling-stroke\"/>\
         <path class=\"contour\" d=\"{contours}\" fill=\"none\" stroke=\"#56b4e9\" stroke-width=\"1.5\" vector-effect=\"non-scaling-stroke\"/></svg>",
        grid.columns(),
        grid.rows()
    )
}

async fn events(
    State(shared): State<Arc<PageState>>,
    client: Option<Extension<Arc<Client>>>,
) -> Result<Response, ApiError> {
    let open = shared.streams.fetch_add(1, Ordering::SeqCst);
    let guard = StreamGuard(shared.clone(), client.map(|c| c.streaming()));
    // At the limit, the oldest stream of the address holding the most makes room (its page
    // opens it again); refused only when no other stream is open.
    if open >= shared.config.max_event_streams && !shared.clients.close_a_stream() {
        return Err(ApiError(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("{open} pages are open already (web.max_event_streams); close one"),
        ));
    }
    let updates = shared.updates.subscribe();
    let stop = shared.stop.clone();
    let stream = futures_util::stream::unfold(
        (updates, stop, guard, true),
        |(mut updates, stop, guard, first)| async move {
            if !first {
                tokio::select! {
                    changed = updates.changed() => changed.ok()?,
                    _ = stop.requested() => return None,
                }
            }
            let version = *updates.borrow_and_update();
            let event = update_event(&guard.0, version);
            Some((
                Ok::<_, std::convert::Infallible>(event),
                (updates, stop, guard, false),
            ))
        },
    );
    // A keep-alive well within the idle timeout keeps an open page's connection.
    let idle = Duration::from_secs(shared.config.idle_timeout_s);
    let every = Duration::from_secs(15)
        .min(idle / 3)
        .max(Duration::from_millis(200));
    Ok(Sse::new(stream)
        .keep_alive(KeepAlive::new().interval(every))
        .into_response())
}

/// Counts an open event stream (and marks its connection) until it ends.
struct StreamGuard(
    Arc<PageState>,
    #[allow(dead_code)] Option<clients::StreamMark>,
);

impl Drop for StreamGuard {
    fn drop(&mut self) {
        self.0.streams.fetch_sub(1, Ordering::SeqCst);
    }
}

/// What an open page is told on every change: the newest layer and the status.
fn update_event(shared: &PageState, version: u64) -> Event {
    let newest = shared
        .timeline
        .read()
        .unwrap_or_else(|e| e.into_inner())
        .newest_with_frames();
    let status = shared
        .status
        .read()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    let data = json!({ "version": version, "newest": newest, "status": status.as_deref() });
    Event::default().event("update").data(data.to_string())
}

async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, ApiError> {
    tokio::task::spawn_blocking(f).await.map_err(|e| {
        ApiError(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("request failed: {e}"),
        )
    })
}

#[derive(Deserialize)]
struct CalibrationRequest {
    layer: u32,
    view: String,
    points: Vec<super::calibration::ClickedPair>,
}

/// The calibration page's save: a new points file, then the registration (when enabled).
async fn calibrate(
    State(shared): State<Arc<PageState>>,
    Json(request): Json<CalibrationRequest>,
) -> Result<Json<super::calibration::CalibrationResult>, ApiError> {
    if !shared.config.calibration_page {
        return Err(ApiError(
            StatusCode::FORBIDDEN,
            "the calibration page is off: set web.calibration_page = true (or serve --calibration-page)".into(),
        ));
    }
    let n = parse_layer(&request.layer.to_string())?;
    let view = parse_view(&request.view)?;
    let original = original_path(&shared, n, view)?;
    let (vectors, numbering) = shared
        .info()
        .and_then(|i| Some((i.vectors_file.clone()?, i.numbering)))
        .ok_or_else(|| bad("the build has no vector file (build.vectors) to register to"))?;
    let _turn = shared
        .encode
        .acquire()
        .await
        .map_err(|_| ApiError(StatusCode::SERVICE_UNAVAILABLE, "shutting down".into()))?;
    let dir = shared.dir.clone();
    blocking(move || {
        super::calibration::save_and_register(
            &dir,
            (&vectors, numbering),
            &original,
            n,
            &view.to_string(),
            &request.points,
            chrono::Utc::now(),
        )
    })
    .await?
    .map(Json)
    .map_err(|e| bad(chain(&e)))
}

async fn overlay(
    State(shared): State<Arc<PageState>>,
    Path(stamp): Path<String>,
) -> Result<Response, ApiError> {
    if !super::calibration::is_stamp(&stamp) {
        return Err(bad("not a calibration of this page"));
    }
    let file = BuildFile::new(
        &shared.dir,
        &[
            super::calibration::CALIBRATION_DIR,
            &format!("overlay-{stamp}.png"),
        ],
    );
    let png = blocking(move || file.read(FileKind::Overlay))
        .await?
        .map_err(|e| file_error(&e))?;
    Ok(([(header::CONTENT_TYPE, "image/png")], png).into_response())
}
