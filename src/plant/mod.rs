//! The plant interfaces (docs/plant.md): Prometheus metrics on the page (`/metrics`), the
//! build's events on an MQTT broker, an OPC UA server (OPC 40540). Each is off
//! until configured, and none can make capture wait: the daemon hands them what happens through
//! a [`PlantSink`] (atomics, `try_send` into bounded channels, a watch of the latest status),
//! and MQTT and OPC UA run on threads of their own (`plant-mqtt`, `plant-opcua`) that outlives
//! each build's run and stop on the shutdown they were started with.

pub mod event;
pub mod live_file;
pub mod metrics;
pub mod mqtt;
#[cfg(feature = "opcua")]
pub mod opcua;
pub mod sink;
mod task;

use crate::config::Config;
use crate::shutdown::Shutdown;
pub use event::{PlantEvent, PlantStatus};
pub use live_file::live_file;
pub use sink::PlantSink;
use std::sync::Arc;
use tracing::warn;

/// The plant interfaces the configuration turns on, running.
pub struct Plant {
    sink: PlantSink,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl Plant {
    /// Starts what `config` turns on (`[metrics] enabled`, `[mqtt] url`); each stops when
    /// `shutdown` is requested (the binary requests it once every run has ended). One that
    /// cannot start (a password file unreadable, a port taken) is logged, never a reason not to
    /// capture.
    pub fn start(config: &Config, shutdown: &Shutdown) -> Plant {
        let live = config
            .metrics
            .enabled
            .then(|| Arc::new(metrics::LiveMetrics::new(&config.views.all())));
        if config.metrics.enabled {
            metrics::install(live.clone());
        }
        let mut sink = sink::SinkBuilder::new(live.clone());
        let mut threads = Vec::new();
        if let Some(live) = &live {
            // The daemon's page is a process of its own: it reads them from this file.
            let feed = sink.consumer("metrics-file");
            match live_file::start(live.clone(), live_file(), feed, shutdown.clone()) {
                Ok(thread) => threads.push(thread),
                Err(e) => warn!(error = %e, "the page's /metrics lacks the daemon's live metrics"),
            }
        }
        match mqtt::prepare(&config.mqtt) {
            Ok(None) => {}
            Ok(Some(mqtt)) => {
                let feed = sink.consumer("mqtt");
                match mqtt.start(feed, live.clone(), shutdown.clone()) {
                    Ok(thread) => threads.push(thread),
                    Err(e) => warn!(error = %crate::logging::Chain(&e), "no MQTT; capture goes on"),
                }
            }
            Err(e) => warn!(error = %crate::logging::Chain(&e), "no MQTT; capture goes on"),
        }
        // A binary without the feature refused `[opcua] listen` in `Config::check_backends`.
        #[cfg(feature = "opcua")]
        match opcua::prepare(&config.opcua) {
            Ok(None) => {}
            Ok(Some(server)) => {
                let feed = sink.consumer("opcua");
                match server.start(feed, shutdown.clone()) {
                    Ok(thread) => threads.push(thread),
                    Err(e) => {
                        warn!(error = %crate::logging::Chain(&e), "no OPC UA server; capture goes on")
                    }
                }
            }
            Err(e) => {
                warn!(error = %crate::logging::Chain(&e), "no OPC UA server; capture goes on")
            }
        }
        Plant {
            sink: sink.build(),
            threads,
        }
    }

    /// Where the daemon hands its events.
    pub fn sink(&self) -> PlantSink {
        self.sink.clone()
    }

    /// Waits for the threads (once the shutdown they were started with is requested).
    pub fn join(self) {
        drop(self.sink);
        for thread in self.threads {
            let _ = thread.join();
        }
    }
}
