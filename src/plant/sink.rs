//! What the daemon tells the plant interfaces, and the hand-off that never makes it wait: a
//! [`PlantSink`] updates the live metrics (atomics), `try_send`s each event into every
//! consumer's bounded channel (full: the event is dropped and counted) and replaces the latest
//! status in a watch. Nothing in it blocks, allocates much or takes a lock held elsewhere for
//! long; when no interface is on, it does nothing at all.

use super::event::{PlantEvent, PlantStatus};
use super::metrics::LiveMetrics;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};

/// Events waiting for one consumer (MQTT); beyond this they are dropped and counted.
pub const CHANNEL_CAPACITY: usize = 1024;

/// A consumer's end: its events and the latest status.
pub struct PlantFeed {
    pub events: mpsc::Receiver<Arc<PlantEvent>>,
    pub status: watch::Receiver<Arc<PlantStatus>>,
}

struct Consumer {
    name: &'static str,
    events: mpsc::Sender<Arc<PlantEvent>>,
}

struct Inner {
    live: Option<Arc<LiveMetrics>>,
    consumers: Vec<Consumer>,
    status: watch::Sender<Arc<PlantStatus>>,
}

/// Where the daemon's threads hand what happened to the plant interfaces. Cheap to clone; the
/// default one is off.
#[derive(Clone, Default)]
pub struct PlantSink(Option<Arc<Inner>>);

impl std::fmt::Debug for PlantSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PlantSink")
            .field("on", &self.0.is_some())
            .finish()
    }
}

/// Builds a sink: its live metrics and its consumers.
pub struct SinkBuilder {
    live: Option<Arc<LiveMetrics>>,
    consumers: Vec<Consumer>,
    status: watch::Sender<Arc<PlantStatus>>,
}

impl SinkBuilder {
    pub fn new(live: Option<Arc<LiveMetrics>>) -> SinkBuilder {
        SinkBuilder {
            live,
            consumers: Vec::new(),
            status: watch::channel(Arc::new(PlantStatus::default())).0,
        }
    }

    /// A consumer named `name` (the `consumer` label of the dropped-events counter).
    pub fn consumer(&mut self, name: &'static str) -> PlantFeed {
        let (events, receiver) = mpsc::channel(CHANNEL_CAPACITY);
        self.consumers.push(Consumer { name, events });
        PlantFeed {
            events: receiver,
            status: self.status.subscribe(),
        }
    }

    /// The sink; off when it has neither live metrics nor a consumer.
    pub fn build(self) -> PlantSink {
        if self.live.is_none() && self.consumers.is_empty() {
            return PlantSink(None);
        }
        PlantSink(Some(Arc::new(Inner {
            live: self.live,
            consumers: self.consumers,
            status: self.status,
        })))
    }
}

impl PlantSink {
    /// A sink that does nothing.
    pub fn off() -> PlantSink {
        PlantSink(None)
    }

    pub fn is_on(&self) -> bool {
        self.0.is_some()
    }

    /// Hands the event `make` builds (only when something listens) to the live metrics and to
    /// every consumer, without waiting: a consumer whose channel is full misses it (counted in
    /// `layerwise_plant_events_dropped_total`).
    pub fn emit(&self, make: impl FnOnce() -> PlantEvent) {
        let Some(inner) = &self.0 else {
            return;
        };
        let event = make();
        if let Some(live) = &inner.live {
            live.observe(&event);
        }
        if inner.consumers.is_empty() {
            return;
        }
        let event = Arc::new(event);
        for consumer in &inner.consumers {
            if consumer.events.try_send(event.clone()).is_err() {
                if let Some(live) = &inner.live {
                    live.dropped(consumer.name);
                }
            }
        }
    }

    /// The daemon's latest status (replaces the one before; never waits).
    pub fn status(&self, make: impl FnOnce() -> PlantStatus) {
        if let Some(inner) = &self.0 {
            if !inner.consumers.is_empty() {
                inner.status.send_replace(Arc::new(make()));
            }
        }
    }

    /// How long processing took for one frame and how long it waited before.
    pub fn processed(&self, took: Duration, lag: Option<Duration>) {
        if let Some(live) = self.0.as_ref().and_then(|i| i.live.as_ref()) {
            live.processed(took, lag);
        }
    }

    /// The live metrics, when Prometheus metrics are on.
    pub fn live(&self) -> Option<&Arc<LiveMetrics>> {
        self.0.as_ref().and_then(|i| i.live.as_ref())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shot::{Light, Phase, Shot};
    use chrono::Utc;

    fn missing(layer: u32) -> PlantEvent {
        PlantEvent::FrameMissing {
            shot: Shot {
                layer,
                phase: Phase::Post,
                light: Light::Top,
            },
            reason: "x".into(),
            at: Utc::now(),
        }
    }

    #[test]
    fn an_off_sink_builds_nothing_and_a_full_channel_drops_without_waiting() {
        PlantSink::off().emit(|| unreachable!("nothing listens"));
        let live = Arc::new(LiveMetrics::new(&[]));
        let mut builder = SinkBuilder::new(Some(live.clone()));
        let mut feed = builder.consumer("mqtt");
        let sink = builder.build();
        for layer in 0..CHANNEL_CAPACITY as u32 + 10 {
            sink.emit(|| missing(layer));
        }
        assert_eq!(live.dropped_count("mqtt"), 10);
        let first = feed.events.try_recv().unwrap();
        assert!(matches!(&*first, PlantEvent::FrameMissing { shot, .. } if shot.layer == 0));
        sink.status(|| PlantStatus {
            layer: Some(3),
            ..PlantStatus::default()
        });
        sink.status(|| PlantStatus {
            layer: Some(4),
            ..PlantStatus::default()
        });
        assert_eq!(
            feed.status.borrow_and_update().layer,
            Some(4),
            "latest only"
        );
    }
}
