//! The parts' metrics over the layers as the drift check sees them (`GET /api/trends`): each
//! layer's value beside the baseline band it was judged against (median ± `drift_z` robust
//! sigmas of the part's earlier unflagged layers: `inspect::drift::Baseline` replayed over
//! inspection.jsonl with the build's own settings) and the layers where a metric left it.

use super::state::PageState;
use crate::build_dir::inspection::{InspectionLog, InspectionRecord};
use crate::build_dir::INSPECTION;
use crate::config::inspection::InspectionConfig;
use crate::inspect::drift::{self, Baseline, METRICS};
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::Arc;

/// Every part's series.
#[derive(Debug, Serialize)]
pub struct Trends {
    pub metrics: [&'static str; 4],
    /// Robust sigmas from the median that make a drift flag (`inspection.drift_z`).
    pub z: f64,
    pub parts: BTreeMap<i64, PartTrend>,
}

/// One part: the layers it was measured on, and per metric a value for each of them.
#[derive(Debug, Default, Serialize)]
pub struct PartTrend {
    pub layers: Vec<u32>,
    pub series: BTreeMap<&'static str, Series>,
}

/// One metric of one part, index by index with [`PartTrend::layers`]; `null` where there is no
/// value (a part too thin for its fused fraction) or no baseline yet.
#[derive(Debug, Default, Serialize)]
pub struct Series {
    pub value: Vec<Option<f64>>,
    pub median: Vec<Option<f64>>,
    pub sigma: Vec<Option<f64>>,
    /// Layers whose value was `z` sigmas or more from the baseline.
    pub drift: Vec<u32>,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// The trends of `records` (any order; the newest record of a layer wins, as on the page).
pub fn trends(records: &[InspectionRecord], cfg: &InspectionConfig) -> Trends {
    let mut by_layer: BTreeMap<u32, &InspectionRecord> = BTreeMap::new();
    for r in records {
        by_layer.insert(r.layer, r);
    }
    // As the inspector builds it (inspect::Inspector::new, and its push after each layer).
    let mut baseline = Baseline::new(cfg.drift_window, cfg.drift_min_layers, cfg.drift_z / 2.0);
    let mut parts: BTreeMap<i64, PartTrend> = BTreeMap::new();
    for (&layer, r) in &by_layer {
        for m in &r.parts {
            let band = baseline.band(m.part);
            let drifted = baseline.check(m, cfg.drift_z);
            let trend = parts.entry(m.part).or_default();
            trend.layers.push(layer);
            for (k, (name, value)) in METRICS.iter().zip(drift::values(m)).enumerate() {
                let s = trend.series.entry(name).or_default();
                s.value.push(finite(value));
                s.median.push(band[k].map(|b| b.0));
                s.sigma.push(band[k].map(|b| b.1));
                if drifted.iter().any(|d| d.metric == *name) {
                    s.drift.push(layer);
                }
            }
        }
        for m in &r.parts {
            let flagged = r.flags.iter().any(|f| f.part == Some(m.part));
            baseline.push(m, flagged);
        }
    }
    Trends {
        metrics: METRICS,
        z: cfg.drift_z,
        parts,
    }
}

/// `GET /api/trends`: the build's trends, from its inspection log and its configuration's
/// drift settings (the defaults before its snapshot exists).
pub(super) async fn get(State(shared): State<Arc<PageState>>) -> Response {
    let path = shared.dir.join(INSPECTION);
    let cfg = shared
        .info()
        .map(|i| i.inspection.clone())
        .unwrap_or_default();
    let read = tokio::task::spawn_blocking(move || {
        if !path.exists() {
            return Ok(Vec::new());
        }
        InspectionLog::read(&path)
    })
    .await;
    match read {
        Ok(Ok(records)) => Json(trends(&records, &cfg)).into_response(),
        Ok(Err(e)) => error(crate::logging::chain(&e)),
        Err(e) => error(format!("request failed: {e}")),
    }
}

fn error(message: String) -> Response {
    (
        StatusCode::INTERNAL_SERVER_ERROR,
        Json(serde_json::json!({ "error": message })),
    )
        .into_response()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::inspection::PartMetrics;

    fn record(layer: u32, post_mean: f64) -> InspectionRecord {
        InspectionRecord {
            layer,
            at: chrono::Utc::now(),
            ms: 1.0,
            views: Vec::new(),
            plate: BTreeMap::new(),
            parts: vec![PartMetrics {
                part: 3,
                post_mean,
                post_contrast: 10.0,
                ..PartMetrics::default()
            }],
            flags: Vec::new(),
            axis: None,
            bed: None,
            notes: Vec::new(),
        }
    }

    #[test]
    fn the_band_follows_the_baseline_and_a_step_out_of_it_is_drift() {
        let cfg = InspectionConfig::default();
        let mut records: Vec<_> = (1..=12)
            .map(|l| record(l, 100.0 + f64::from(l % 3)))
            .collect();
        records.push(record(13, 160.0));
        // An older record of layer 5 is replaced by the newer one after it.
        records.insert(0, record(5, 500.0));
        let t = trends(&records, &cfg);
        let part = &t.parts[&3];
        assert_eq!(part.layers, (1..=13).collect::<Vec<_>>());
        let s = &part.series["post_mean"];
        assert_eq!(s.value[4], Some(100.0 + 2.0));
        let first = cfg.drift_min_layers;
        assert!(s.median[..first].iter().all(Option::is_none), "{s:?}");
        let (m, sigma) = (s.median[12].unwrap(), s.sigma[12].unwrap());
        assert!((m - 101.0).abs() <= 1.0 && sigma > 0.0, "{m} {sigma}");
        assert!((160.0 - m) / sigma >= cfg.drift_z);
        assert_eq!(s.drift, vec![13]);
        assert!(part.series["fused_fraction"]
            .value
            .iter()
            .all(Option::is_none));
    }
}
