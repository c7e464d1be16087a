//! Inspection in the processing worker: each stored original is rectified once, written to its
//! series and, for the views the inspection uses, reduced to cells; a layer is inspected as soon
//! as its views are in. Records go to `inspection.jsonl`, each flag to the log at WARN, and a
//! flag at or above `inspection.alarm.severity` switches the stack light on. The capture path
//! never waits for any of it.

use crate::build_dir::inspection::{InspectionLog, InspectionRecord, Severity};
use crate::clock::SharedClock;
use crate::config::inspection::{AlarmConfig, AlarmSeverity};
use crate::config::Config;
use crate::hardware::lights::Lights;
use crate::inspect::{Inspector, Reducer};
use crate::series::{FrameProcessor, LiveSeries, ProcessError};
use crate::shot::{Light, Shot};
use std::path::Path;
use std::sync::Mutex;
use tracing::{error, info, warn};

/// The stack light: one channel of a relay board or GPIO set, on while a flag is open.
pub struct Alarm {
    output: Box<dyn Lights>,
    channel: Light,
    level: Severity,
    latch: bool,
    on: bool,
}

impl Alarm {
    pub fn new(output: Box<dyn Lights>, config: &AlarmConfig) -> Alarm {
        Alarm {
            output,
            channel: config.channel,
            level: match config.severity {
                AlarmSeverity::Warning => Severity::Warning,
                AlarmSeverity::Critical => Severity::Critical,
            },
            latch: config.latch,
            on: false,
        }
    }

    /// Switches on for a record with a flag at the alarm's severity; off after a clean layer
    /// unless latched.
    pub fn after_layer(&mut self, record: &InspectionRecord) {
        let raised = record.flags.iter().find(|f| f.severity >= self.level);
        match raised {
            Some(flag) if !self.on => match self.output.switch(self.channel, true) {
                Ok(()) => {
                    self.on = true;
                    warn!(layer = record.layer, kind = %flag.kind, channel = %self.channel, "inspection alarm ON: layer {}: {}", record.layer, flag.message);
                }
                Err(e) => error!(error = %e, "inspection alarm: cannot switch the stack light on"),
            },
            None if self.on && !self.latch => match self.output.switch(self.channel, false) {
                Ok(()) => {
                    self.on = false;
                    info!(
                        layer = record.layer,
                        "inspection alarm off: layer {} is clean", record.layer
                    );
                }
                Err(e) => error!(error = %e, "inspection alarm: cannot switch the stack light off"),
            },
            _ => {}
        }
    }
}

/// The live series plus the inspection of every layer.
pub struct InspectingSeries {
    live: LiveSeries,
    reducer: Reducer,
    inspector: Mutex<Inspector>,
    log: Mutex<InspectionLog>,
    alarm: Mutex<Alarm>,
    clock: SharedClock,
}

impl InspectingSeries {
    /// Opens `inspection.jsonl` (resuming after the layers it holds) and the inspector on the
    /// series' grid with the build's vectors.
    pub fn open(
        config: &Config,
        build_dir: &Path,
        live: LiveSeries,
        alarm: Alarm,
        clock: SharedClock,
    ) -> Result<InspectingSeries, super::AcquisitionError> {
        let vectors = match &config.build.vectors {
            Some(path) => Some(crate::vectors::LayerIndex::build(path).map_err(|e| {
                super::AcquisitionError::Series(crate::series::SeriesError::Vectors(e))
            })?),
            None => {
                warn!("inspection: no build.vectors, so only streaks and short feed are looked for (parts need the vector file)");
                None
            }
        };
        let mut inspector = Inspector::new(
            &config.inspection,
            live.grid(),
            &config.views.all(),
            vectors,
        );
        let (log, done) = InspectionLog::open(
            &build_dir.join(crate::build_dir::INSPECTION),
            config.storage.fsync,
        )?;
        if !done.is_empty() {
            info!(
                layers = done.len(),
                "inspection: resuming after the layers already inspected"
            );
        }
        inspector.resume(&done);
        Ok(InspectingSeries {
            live,
            reducer: inspector.reducer(),
            inspector: Mutex::new(inspector),
            log: Mutex::new(log),
            alarm: Mutex::new(alarm),
            clock,
        })
    }

    fn record(&self, record: &InspectionRecord) {
        for flag in &record.flags {
            let line = crate::inspect::describe(record.layer, flag);
            if flag.severity >= Severity::Warning {
                warn!(layer = record.layer, kind = %flag.kind, severity = %flag.severity, part = flag.part, "{line}");
            } else {
                info!(layer = record.layer, kind = %flag.kind, "{line}");
            }
        }
        if let Ok(mut log) = self.log.lock() {
            if let Err(e) = log.append(record) {
                error!(error = %e, layer = record.layer, "inspection: cannot write the record");
            }
        }
        if let Ok(mut alarm) = self.alarm.lock() {
            alarm.after_layer(record);
        }
    }
}

impl FrameProcessor for InspectingSeries {
    fn process(&self, build_dir: &Path, shot: Shot, original: &Path) -> Result<(), ProcessError> {
        let (bytes, acquired) = crate::series::read_original(original)?;
        let rectified = self.live.rectified_luma(&bytes)?;
        let cells = self
            .reducer
            .needs(shot.view())
            .then(|| self.reducer.cells(&rectified));
        self.live
            .write_rectified(build_dir, shot, rectified, acquired)?;
        if let Some(cells) = cells {
            let records = match self.inspector.lock() {
                Ok(mut inspector) => {
                    inspector.add(shot.layer, shot.view(), cells, self.clock.now())
                }
                Err(_) => Vec::new(),
            };
            for record in &records {
                self.record(record);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::inspection::{Flag, FlagKind};
    use crate::hardware::lights::LightsError;
    use std::sync::{Arc, Mutex};

    /// Records what it is told.
    struct Recorder(Arc<Mutex<Vec<(Light, bool)>>>);

    impl Lights for Recorder {
        fn switch(&mut self, light: Light, on: bool) -> Result<(), LightsError> {
            self.0.lock().unwrap().push((light, on));
            Ok(())
        }
        fn all_off(&mut self) -> Result<(), LightsError> {
            Ok(())
        }
    }

    fn record(layer: u32, severity: Option<Severity>) -> InspectionRecord {
        InspectionRecord {
            layer,
            at: chrono::DateTime::from_timestamp(0, 0).unwrap(),
            ms: 0.0,
            views: vec![],
            plate: Default::default(),
            parts: vec![],
            flags: severity
                .map(|severity| Flag {
                    kind: FlagKind::Spatter,
                    severity,
                    part: None,
                    view: "post_top".into(),
                    bbox_mm: [0.0; 4],
                    bbox_px: [0; 4],
                    score: 2.0,
                    threshold: 1.0,
                    message: "spot".into(),
                })
                .into_iter()
                .collect(),
        }
    }

    #[test]
    fn the_alarm_switches_at_its_severity_and_latches_or_not() {
        let log = Arc::new(Mutex::new(Vec::new()));
        let mut config = AlarmConfig {
            channel: Light::Side,
            ..AlarmConfig::default()
        };
        let mut alarm = Alarm::new(Box::new(Recorder(log.clone())), &config);
        alarm.after_layer(&record(1, Some(Severity::Warning)));
        assert!(
            log.lock().unwrap().is_empty(),
            "below the default (critical)"
        );
        alarm.after_layer(&record(2, Some(Severity::Critical)));
        alarm.after_layer(&record(3, Some(Severity::Critical)));
        alarm.after_layer(&record(4, None));
        assert_eq!(
            *log.lock().unwrap(),
            vec![(Light::Side, true)],
            "latched, switched once"
        );

        log.lock().unwrap().clear();
        config.latch = false;
        config.severity = AlarmSeverity::Warning;
        let mut alarm = Alarm::new(Box::new(Recorder(log.clone())), &config);
        alarm.after_layer(&record(1, Some(Severity::Warning)));
        alarm.after_layer(&record(2, None));
        assert_eq!(
            *log.lock().unwrap(),
            vec![(Light::Side, true), (Light::Side, false)]
        );
    }
}
