//! Prometheus metrics (`GET /metrics`, docs/metrics.md) in the Prometheus text format 0.0.4
//! (prometheus-client's `prometheus_text` encoder, which `promtool check metrics` accepts).
//!
//! Two kinds: the build's state, made at each scrape from the status report the page keeps
//! (so `layerwise serve` has them too), and the daemon's live metrics ([`LiveMetrics`]:
//! latency histograms and counters since the process started), updated by the capture and
//! processing threads with atomic operations on label sets made at start. Labels only take
//! values from fixed sets (views, parts of the machine, flag kinds and severities, archives).

use super::event::PlantEvent;
use crate::build_dir::alarm::{AlarmEvent, AlarmState};
use crate::build_dir::inspection::{FlagKind, Severity};
use crate::build_dir::status::{HealthState, StatusReport, HEALTH_PARTS};
use crate::shot::View;
use chrono::{DateTime, Utc};
use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, EncodeLabelSet, EncodeMetric};
use prometheus_client::metrics::counter::{ConstCounter, Counter};
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::{ConstGauge, Gauge};
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::metrics::MetricType;
use prometheus_client::registry::Registry;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

/// The `Content-Type` of what [`render`] returns.
pub const CONTENT_TYPE: &str = prometheus_client::encoding::prometheus_text::CONTENT_TYPE;

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct ViewLabel {
    view: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct FlagLabels {
    kind: String,
    severity: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct ConsumerLabel {
    consumer: String,
}

fn histogram(start: f64) -> Histogram {
    Histogram::new(exponential_buckets(start, 2.0, 10))
}

/// The daemon's own metrics: what happened since the process started.
#[derive(Debug)]
pub struct LiveMetrics {
    capture: Family<ViewLabel, Histogram>,
    layer_capture: Histogram,
    processing: Histogram,
    processing_lag: Histogram,
    flags: Family<FlagLabels, Counter>,
    alarms_raised: Counter,
    dropped: Family<ConsumerLabel, Counter>,
    pub mqtt: MqttGauges,
}

/// What the MQTT thread reports.
#[derive(Debug, Default)]
pub struct MqttGauges {
    pub connected: Gauge,
    pub queue_messages: Gauge,
    pub queue_bytes: Gauge,
    pub published: Counter,
    /// Messages dropped because the queue was full.
    pub dropped: Counter,
}

impl LiveMetrics {
    /// Label sets for `views` and for every flag kind and severity are made now, so the capture
    /// path only ever takes a read lock and an atomic operation.
    pub fn new(views: &[View]) -> LiveMetrics {
        let live = LiveMetrics {
            capture: Family::new_with_constructor(|| histogram(0.05)),
            layer_capture: histogram(0.1),
            processing: histogram(0.01),
            processing_lag: histogram(0.1),
            flags: Family::default(),
            alarms_raised: Counter::default(),
            dropped: Family::default(),
            mqtt: MqttGauges::default(),
        };
        for view in views {
            let _ = live.capture.get_or_create(&ViewLabel {
                view: view.to_string(),
            });
        }
        for kind in FlagKind::ALL {
            for severity in [Severity::Info, Severity::Warning, Severity::Critical] {
                let _ = live.flags.get_or_create(&FlagLabels {
                    kind: kind.name().into(),
                    severity: severity.to_string(),
                });
            }
        }
        let _ = live.dropped.get_or_create(&ConsumerLabel {
            consumer: "mqtt".into(),
        });
        live
    }

    /// Counts what an event says.
    pub(super) fn observe(&self, event: &PlantEvent) {
        match event {
            PlantEvent::FrameStored(frame) => {
                let seconds = (frame.capture_ms + frame.download_ms) / 1000.0;
                self.capture
                    .get_or_create(&ViewLabel {
                        view: frame.shot.view().to_string(),
                    })
                    .observe(seconds);
            }
            PlantEvent::PhaseDone { signal_at, at, .. } => {
                let took = (*at - *signal_at).num_milliseconds().max(0) as f64 / 1000.0;
                self.layer_capture.observe(took);
            }
            PlantEvent::Inspected(record) => {
                for flag in &record.flags {
                    self.flags
                        .get_or_create(&FlagLabels {
                            kind: flag.kind.name().into(),
                            severity: flag.severity.to_string(),
                        })
                        .inc();
                }
            }
            PlantEvent::Alarm(AlarmEvent::Raised { .. }) => {
                self.alarms_raised.inc();
            }
            _ => {}
        }
    }

    pub(super) fn processed(&self, took: Duration, lag: Option<Duration>) {
        self.processing.observe(took.as_secs_f64());
        if let Some(lag) = lag {
            self.processing_lag.observe(lag.as_secs_f64());
        }
    }

    pub(super) fn dropped(&self, consumer: &str) {
        self.dropped
            .get_or_create(&ConsumerLabel {
                consumer: consumer.into(),
            })
            .inc();
    }

    #[cfg(test)]
    pub(super) fn dropped_count(&self, consumer: &str) -> u64 {
        self.dropped
            .get_or_create(&ConsumerLabel {
                consumer: consumer.into(),
            })
            .get()
    }

    fn register(&self, registry: &mut Registry) {
        registry.register(
            "layerwise_capture_duration_seconds",
            "Camera capture and download of one frame",
            self.capture.clone(),
        );
        registry.register(
            "layerwise_layer_capture_duration_seconds",
            "From a layer signal until every light of it is done",
            self.layer_capture.clone(),
        );
        registry.register(
            "layerwise_processing_duration_seconds",
            "Rectification, DICOM and inspection of one frame",
            self.processing.clone(),
        );
        registry.register(
            "layerwise_processing_lag_seconds",
            "From a frame's hand-over to processing until it is processed",
            self.processing_lag.clone(),
        );
        registry.register(
            "layerwise_inspection_flags",
            "Inspection flags since the daemon started",
            self.flags.clone(),
        );
        registry.register(
            "layerwise_alarm_raises",
            "Times the inspection alarm was raised since the daemon started",
            self.alarms_raised.clone(),
        );
        registry.register(
            "layerwise_plant_events_dropped",
            "Events a plant interface missed because its queue was full",
            self.dropped.clone(),
        );
        let mqtt = &self.mqtt;
        for (name, help, gauge) in [
            (
                "layerwise_mqtt_connected",
                "1 while connected to the MQTT broker",
                &mqtt.connected,
            ),
            (
                "layerwise_mqtt_queue_messages",
                "MQTT messages waiting for the broker",
                &mqtt.queue_messages,
            ),
            (
                "layerwise_mqtt_queue_bytes",
                "Bytes of the MQTT messages waiting for the broker",
                &mqtt.queue_bytes,
            ),
        ] {
            registry.register(name, help, gauge.clone());
        }
        registry.register(
            "layerwise_mqtt_published",
            "MQTT messages the broker acknowledged",
            mqtt.published.clone(),
        );
        registry.register(
            "layerwise_mqtt_dropped",
            "MQTT messages dropped because the queue was full",
            mqtt.dropped.clone(),
        );
    }
}

/// Where the daemon's live metrics come from for `/metrics`.
#[derive(Debug)]
enum Live {
    /// This process is the daemon (the demo's page, in its process).
    Here(Arc<LiveMetrics>),
    /// The daemon's page process: the file the daemon keeps them in (`plant::live_file`).
    File(std::path::PathBuf),
}

/// What `/metrics` serves in this process: set once, by `layerwise run`/`demo` when
/// `[metrics] enabled` (with the daemon's live metrics), by the daemon's page process (from the
/// daemon's file) or by `layerwise serve --metrics`.
#[derive(Debug)]
pub struct Exporter {
    live: Option<Live>,
}

static EXPORTER: OnceLock<Exporter> = OnceLock::new();

/// Turns `/metrics` on for this process (the first call wins).
pub fn install(live: Option<Arc<LiveMetrics>>) {
    let _ = EXPORTER.set(Exporter {
        live: live.map(Live::Here),
    });
}

/// Turns `/metrics` on for the daemon's page process: the live metrics are read from the file
/// the daemon keeps them in at each scrape (the first call wins).
pub fn install_from_file(path: std::path::PathBuf) {
    let _ = EXPORTER.set(Exporter {
        live: Some(Live::File(path)),
    });
}

/// The metrics in the Prometheus text format; None when metrics are off in this process.
pub fn render(status: Option<Arc<StatusReport>>, now: DateTime<Utc>) -> Option<String> {
    let exporter = EXPORTER.get()?;
    Some(match &exporter.live {
        Some(Live::Here(live)) => encode(status, Some(live), now),
        Some(Live::File(path)) => {
            let mut text = encode(status, None, now);
            text.push_str(&read_live(path));
            text
        }
        None => encode(status, None, now),
    })
}

/// The largest live-metrics text read back from the daemon's file (a few KB in practice).
const MAX_LIVE_BYTES: u64 = 4 << 20;

/// The daemon's live metrics' text in `path` (`plant::live_file`; nothing while the daemon has
/// not written it yet).
fn read_live(path: &std::path::Path) -> String {
    crate::fsutil::read_bounded(path, MAX_LIVE_BYTES)
        .ok()
        .and_then(|bytes| String::from_utf8(bytes).ok())
        .unwrap_or_default()
}

/// The state of `status` (when there is one yet) and the live metrics.
pub fn encode(
    status: Option<Arc<StatusReport>>,
    live: Option<&LiveMetrics>,
    now: DateTime<Utc>,
) -> String {
    let mut registry = Registry::default();
    if let Some(status) = status {
        registry.register_collector(Box::new(State { status, now }));
    }
    if let Some(live) = live {
        live.register(&mut registry);
    }
    let mut text = String::with_capacity(16 << 10);
    // Writing into a String cannot fail.
    let _ = prometheus_client::encoding::prometheus_text::encode(&mut text, &registry);
    text
}

/// The build's state at one scrape.
#[derive(Debug)]
struct State {
    status: Arc<StatusReport>,
    now: DateTime<Utc>,
}

type Labels = Vec<(&'static str, String)>;

/// One metric family of constant values.
fn family<M: EncodeMetric>(
    encoder: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    kind: MetricType,
    samples: impl IntoIterator<Item = (Labels, M)>,
) -> Result<(), std::fmt::Error> {
    let mut samples = samples.into_iter().peekable();
    if samples.peek().is_none() {
        return Ok(());
    }
    let mut metric = encoder.encode_descriptor(name, help, None, kind)?;
    for (labels, value) in samples {
        value.encode(metric.encode_family(&labels)?)?;
    }
    Ok(())
}

fn gauge(
    encoder: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    value: Option<f64>,
) -> Result<(), std::fmt::Error> {
    family(
        encoder,
        name,
        help,
        MetricType::Gauge,
        value.map(|v| (Vec::new(), ConstGauge::new(v))),
    )
}

fn seconds(at: DateTime<Utc>) -> f64 {
    at.timestamp_millis() as f64 / 1000.0
}

impl Collector for State {
    fn encode(&self, mut e: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let s = &*self.status;
        let g = MetricType::Gauge;
        let c = MetricType::Counter;
        family(
            &mut e,
            "layerwise_build_info",
            "The build being recorded or served (always 1)",
            g,
            [(
                vec![("build", s.name.clone().unwrap_or_default())],
                ConstGauge::new(1i64),
            )],
        )?;
        gauge(
            &mut e,
            "layerwise_daemon_running",
            "1 while the daemon records this build",
            Some(f64::from(u8::from(s.state == "running"))),
        )?;
        gauge(
            &mut e,
            "layerwise_layer",
            "Layer of the last layer signal",
            s.layer.map(f64::from),
        )?;
        gauge(
            &mut e,
            "layerwise_layers_expected",
            "Layers the build will have ([build] layers)",
            s.layers_expected.map(f64::from),
        )?;
        family(
            &mut e,
            "layerwise_layers_captured",
            "Layers with at least one frame stored",
            c,
            [(Vec::new(), ConstCounter::new(s.layers_seen as u64))],
        )?;
        let views = || s.frames_by_view.iter();
        family(
            &mut e,
            "layerwise_frames_stored",
            "Frames stored (first takes)",
            c,
            views().map(|(v, n)| {
                (
                    vec![("view", v.clone())],
                    ConstCounter::new(n.stored as u64),
                )
            }),
        )?;
        family(
            &mut e,
            "layerwise_frames_missing",
            "Frames recorded as missing",
            c,
            views().map(|(v, n)| {
                (
                    vec![("view", v.clone())],
                    // Ever recorded: a counter never goes down (a frame a retake stored
                    // later stays counted; Prometheus would read a drop as a reset).
                    ConstCounter::new(n.recorded_missing as u64),
                )
            }),
        )?;
        family(
            &mut e,
            "layerwise_frames_retaken",
            "Frames taken again for repeated signals",
            c,
            [(Vec::new(), ConstCounter::new(s.retakes as u64))],
        )?;
        gauge(
            &mut e,
            "layerwise_processing_backlog_frames",
            "Frames stored whose series slice is not written yet",
            Some(s.waiting_for_processing as f64),
        )?;
        gauge(
            &mut e,
            "layerwise_processing_paused",
            "1 while derived data waits for disk space",
            s.disk
                .as_ref()
                .map(|d| f64::from(u8::from(d.derived_paused))),
        )?;
        let alarm = match &s.alarm {
            None | Some(AlarmState::Off) => "off",
            Some(AlarmState::Raised { .. }) => "raised",
            Some(AlarmState::Acknowledged { .. }) => "acknowledged",
            Some(AlarmState::Unreadable { .. }) => "unreadable",
        };
        family(
            &mut e,
            "layerwise_alarm_state",
            "1 for the inspection alarm's current state",
            g,
            ["off", "raised", "acknowledged", "unreadable"].map(|state| {
                (
                    vec![("state", state.to_string())],
                    ConstGauge::new(i64::from(state == alarm)),
                )
            }),
        )?;
        let health = HEALTH_PARTS
            .iter()
            .filter_map(|part| s.health.get(*part).map(|h| (*part, h.state)));
        family(
            &mut e,
            "layerwise_health_state",
            "1 for each part's current state (ok, warning, error)",
            g,
            health.flat_map(|(part, state)| {
                [
                    ("ok", HealthState::Ok),
                    ("warning", HealthState::Warning),
                    ("error", HealthState::Error),
                ]
                .map(|(name, value)| {
                    (
                        vec![("part", part.to_string()), ("state", name.to_string())],
                        ConstGauge::new(i64::from(state == value)),
                    )
                })
            }),
        )?;
        gauge(
            &mut e,
            "layerwise_disk_free_bytes",
            "Free bytes on the build disk",
            s.free_bytes.map(|b| b as f64),
        )?;
        gauge(
            &mut e,
            "layerwise_disk_reserve_bytes",
            "Free space kept spare (storage.min_free_gb)",
            s.disk.as_ref().map(|d| d.min_free_bytes as f64),
        )?;
        gauge(
            &mut e,
            "layerwise_disk_needed_bytes",
            "Forecast: bytes the rest of the build needs",
            s.bytes_needed.map(|b| b as f64),
        )?;
        family(
            &mut e,
            "layerwise_build_written_bytes",
            "Bytes the build has written, per kind of file",
            g,
            s.bytes_by_kind
                .iter()
                .map(|(k, b)| (vec![("kind", k.clone())], ConstGauge::new(*b as f64))),
        )?;
        let pacs = |pick: fn(&crate::build_dir::pushlog::PushSummary) -> usize| {
            s.pacs.iter().map(move |p| {
                (
                    vec![("destination", p.destination.clone())],
                    ConstGauge::new(pick(p) as f64),
                )
            })
        };
        family(
            &mut e,
            "layerwise_pacs_pending_instances",
            "Instances waiting to be pushed to an archive",
            g,
            pacs(|p| p.pending),
        )?;
        family(
            &mut e,
            "layerwise_pacs_pushed_instances",
            "Instances the archive confirmed",
            g,
            pacs(|p| p.pushed),
        )?;
        family(
            &mut e,
            "layerwise_pacs_failed_instances",
            "Instances the archive refused",
            g,
            pacs(|p| p.failed),
        )?;
        if let Some(trigger) = &s.trigger {
            family(
                &mut e,
                "layerwise_trigger_connected",
                "1 while the layer signal's source is connected",
                g,
                [(
                    vec![("source", trigger.source.clone())],
                    ConstGauge::new(i64::from(trigger.connected)),
                )],
            )?;
            let last = trigger.last_signal_at;
            gauge(
                &mut e,
                "layerwise_trigger_last_signal_timestamp_seconds",
                "When the last layer signal came (Unix time)",
                last.map(seconds),
            )?;
            gauge(
                &mut e,
                "layerwise_trigger_last_signal_age_seconds",
                "Seconds since the last layer signal",
                last.map(|at| (seconds(self.now) - seconds(at)).max(0.0)),
            )?;
        }
        gauge(
            &mut e,
            "layerwise_status_updated_timestamp_seconds",
            "When the daemon last wrote status.json (Unix time)",
            s.updated_at.map(seconds),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::{Journal, Record};
    use crate::shot::{Light, Phase};

    #[test]
    fn the_state_of_a_build_and_the_live_metrics_in_the_prometheus_text_format() {
        let dir = tempfile::tempdir().unwrap();
        let (mut journal, _) =
            Journal::open(&dir.path().join(crate::build_dir::JOURNAL), false).unwrap();
        let at = chrono::Utc::now();
        for layer in 1..=3 {
            journal
                .append(&Record::Event {
                    layer,
                    phase: Phase::Post,
                    at,
                })
                .unwrap();
            journal
                .append(&Record::Frame {
                    layer,
                    phase: Phase::Post,
                    light: Light::Top,
                    file: format!("raw/L{layer:05}_post_top.jpg"),
                    bytes: 10,
                    sha256: "00".into(),
                    at,
                })
                .unwrap();
        }
        journal
            .append(&Record::Missing {
                layer: 3,
                phase: Phase::Post,
                light: Light::Side,
                reason: "camera failed".into(),
                at,
            })
            .unwrap();
        // Missing, then stored by the retake of a repeated signal: counted all the same.
        for record in [
            Record::Missing {
                layer: 2,
                phase: Phase::Post,
                light: Light::Front,
                reason: "camera busy".into(),
                at,
            },
            Record::Frame {
                layer: 2,
                phase: Phase::Post,
                light: Light::Front,
                file: "raw/L00002_post_front.jpg".into(),
                bytes: 10,
                sha256: "00".into(),
                at,
            },
        ] {
            journal.append(&record).unwrap();
        }
        let report = crate::build_dir::status::report(dir.path(), Default::default()).unwrap();
        assert_eq!(report.frames_missing, 1);
        let views = [View {
            phase: Phase::Post,
            light: Light::Top,
        }];
        let live = LiveMetrics::new(&views);
        live.processed(Duration::from_millis(120), Some(Duration::from_secs(2)));
        let text = encode(Some(Arc::new(report)), Some(&live), at);
        for line in [
            "# TYPE layerwise_layers_captured_total counter",
            "layerwise_layers_captured_total 3",
            "layerwise_layer 3.0",
            "layerwise_frames_stored_total{view=\"post_top\"} 3",
            "layerwise_frames_missing_total{view=\"post_side\"} 1",
            "layerwise_frames_missing_total{view=\"post_front\"} 1",
            "layerwise_alarm_state{state=\"off\"} 1",
            "layerwise_processing_duration_seconds_count 1",
            "layerwise_processing_lag_seconds_bucket{le=\"3.2\"} 1",
            "layerwise_inspection_flags_total{kind=\"spatter\",severity=\"critical\"} 0",
            "# HELP layerwise_capture_duration_seconds Camera capture and download of one frame.",
        ] {
            assert!(
                text.lines().any(|l| l == line),
                "{line} missing in:\n{text}"
            );
        }
        // Without a status yet (no journal read), the live metrics alone.
        let text = encode(None, Some(&live), at);
        assert!(!text.contains("layerwise_layer "));
        assert!(text.contains("layerwise_mqtt_connected 0"));
    }
}
