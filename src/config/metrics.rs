//! `[metrics]`: Prometheus metrics (src/plant/metrics, docs/metrics.md) at `GET /metrics` on the
//! operator page's listener (`[web] listen`, and its token when `web.token_file` is set).

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MetricsConfig {
    /// Serve `/metrics` (off by default).
    pub enabled: bool,
}
