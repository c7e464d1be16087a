//! Inspection in the processing worker: each stored original is rectified once, written to its
//! series and, for the views the inspection uses, reduced to cells; a layer is inspected as soon
//! as its views are in. Records go to `inspection.jsonl`, each flag to the log at WARN, and a
//! flag at or above `inspection.alarm.severity` switches the stack light on
//! ([`super::alarm`]). The capture path never waits for any of it.

use super::alarm::{Alarm, AlarmThread};
use super::model::ModelFlight;
use crate::build_dir::inspection::{InspectionLog, InspectionRecord, Severity};
use crate::clock::ms_since;
use crate::clock::SharedClock;
use crate::config::Config;
use crate::inspect::{InFlight, Inspector, Reducer};
use crate::logging::Chain;
use crate::rectify::FrameLuma;
use crate::series::{commit_then, FrameProcessor, LiveSeries, ProcessError, StepTimes, Then};
use crate::shot::Shot;
use std::path::Path;
use std::sync::Mutex;
use std::time::Instant;
use tracing::{error, info, warn};

/// The live series plus the inspection of every layer.
pub struct InspectingSeries {
    live: LiveSeries,
    /// The takes the slices show of the layers processed before a stop but never inspected:
    /// the worker processes them again first ([`FrameProcessor::catch_up`]).
    missed: Vec<(Shot, u32, String)>,
    reducer: Reducer,
    inspector: Mutex<Inspector>,
    log: Mutex<InspectionLog>,
    alarm: AlarmThread,
    clock: SharedClock,
    /// `[inspection.model]`: the trained model after the classical checks.
    model: Option<super::model::ModelStage>,
    plant: crate::plant::PlantSink,
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
                warn!("inspection: no build.vectors, so only the plate-wide checks run (streaks, short feed, coverage; parts need the vector file)");
                None
            }
        };
        let mut inspector = Inspector::new(
            &config.inspection,
            live.grid(),
            &config.views.all(),
            vectors,
        );
        if let Some(footprint) = crate::inspect::camera_footprint_mm(live.camera(), &live.grid()) {
            let tolerance = inspector.resolve_camera(footprint);
            info!(
                camera_mm_per_px = format!("{footprint:.3}"),
                fusion_tolerance_mm = format!("{tolerance:.2}"),
                "inspection: the camera resolves the plate to {footprint:.2} mm per pixel at worst"
            );
        }
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
        let missed = missed_layers(build_dir, &inspector, &config.views.all())?;
        let model = open_model(config, build_dir, &live)?;
        let mut alarm = alarm;
        alarm.resume(build_dir, config.storage.fsync)?;
        let alarm = AlarmThread::spawn(alarm, build_dir.to_path_buf(), clock.clone());
        Ok(InspectingSeries {
            live,
            missed,
            reducer: inspector.reducer(),
            inspector: Mutex::new(inspector),
            log: Mutex::new(log),
            alarm,
            clock,
            model,
            plant: crate::plant::PlantSink::off(),
        })
    }

    /// Also tells the plant interfaces each layer's record.
    pub fn with_plant(mut self, plant: crate::plant::PlantSink) -> InspectingSeries {
        self.plant = plant;
        self
    }

    fn record(&self, record: &InspectionRecord) {
        for note in &record.notes {
            if note.level == "warn" {
                warn!(layer = record.layer, "inspection: {}", note.message);
            } else {
                info!(layer = record.layer, "inspection: {}", note.message);
            }
        }
        for flag in &record.flags {
            let line = crate::inspect::describe(record.layer, flag);
            if flag.since.is_some() {
                // A flag that persists was logged on its first layer.
                info!(layer = record.layer, kind = %flag.kind, since = flag.since, "{line}");
            } else if flag.severity >= Severity::Warning {
                warn!(layer = record.layer, kind = %flag.kind, severity = %flag.severity, part = flag.part, "{line}");
            } else {
                info!(layer = record.layer, kind = %flag.kind, "{line}");
            }
        }
        if let Ok(mut log) = self.log.lock() {
            if let Err(e) = log.append(record) {
                error!(error = %Chain(&e), layer = record.layer, "inspection: cannot write the record");
            }
        }
        self.plant
            .emit(|| crate::plant::PlantEvent::Inspected(std::sync::Arc::new(record.clone())));
        self.alarm.after_layer(record);
    }
}

impl InspectingSeries {
    /// The records with the model's flags added (those the model is done with), or as they are
    /// without a model.
    fn with_model(&self, records: Vec<InspectionRecord>, flush: bool) -> Vec<InspectionRecord> {
        match &self.model {
            Some(model) => model.complete(records, flush),
            None => records,
        }
    }
}

/// The configured model, checked against the series' views: a bad model file stops the start.
fn open_model(
    config: &Config,
    build_dir: &Path,
    live: &LiveSeries,
) -> Result<Option<super::model::ModelStage>, super::AcquisitionError> {
    let Some(cfg) = &config.inspection.model else {
        return Ok(None);
    };
    let model = crate::learn::live::LiveModel::open(cfg, &live.grid())
        .map_err(super::AcquisitionError::Model)?;
    Ok(Some(super::model::ModelStage::new(
        model,
        live.grid(),
        &config.views.all(),
        build_dir,
        config.storage.fsync,
    )))
}

impl FrameProcessor for InspectingSeries {
    fn fault(&self) -> Option<String> {
        self.alarm.fault()
    }

    fn process(&self, build_dir: &Path, shot: Shot, original: &Path) -> Result<(), ProcessError> {
        self.process_take_then(build_dir, shot, 1, original)?()
    }

    fn process_take(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
    ) -> Result<(), ProcessError> {
        self.process_take_then(build_dir, shot, take, original)?()
    }

    /// The slice is written, then the layer inspected once its views are in (its record, the
    /// alarm), while the slice's commit waits for the disk on the worker's commit thread. The
    /// inspection looks at the rectified view, not the file: a commit that then fails (an I/O
    /// error at the fsync) leaves the layer inspected and the frame journaled as failed, its
    /// original kept. A retake replaces the slice (`[series] take = "last"`); the layer was
    /// inspected on its first take and is not inspected again.
    fn process_take_then(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
    ) -> Result<Then<'_>, ProcessError> {
        if take > 1 {
            return self.live.process_take_then(build_dir, shot, take, original);
        }
        let mut steps = StepTimes::default();
        // Given up when dropped with a view still in it (the processing failed before the view
        // was scanned, or before its cells landed).
        let mut flight = Flight::begin(self, shot);
        let see = |rectified: &FrameLuma, steps: &mut StepTimes| {
            if let Some(model) = &self.model {
                model.scan(shot.layer, shot.view(), rectified, flight.model.take());
            }
            let started = Instant::now();
            let cells = self
                .reducer
                .needs(shot.view())
                .then(|| self.reducer.cells(rectified));
            steps.cells_ms = ms_since(started);
            cells
        };
        let (pending, cells) = self
            .live
            .write_original_seen(build_dir, shot, 1, original, &mut steps, see)?;
        let records = match (flight.inspection.take(), self.inspector.lock()) {
            (Some(f), Ok(mut inspector)) => match cells {
                Some(cells) => inspector.land(f, cells, self.clock.now()),
                None => inspector.give_up(f, self.clock.now()),
            },
            _ => Vec::new(),
        };
        for record in &self.with_model(records, false) {
            self.record(record);
        }
        Ok(commit_then(pending, steps, shot))
    }

    /// At the build's end the layers still waiting for a view (one the camera never gave) are
    /// inspected with the views they have; the alarm handles the last layers' records, then its
    /// thread ends. A run stopped before its build's end leaves them to the next start, which
    /// inspects them with all their views.
    fn finish(&self, ended: bool) {
        let waiting = match (ended, self.inspector.lock()) {
            (true, Ok(mut inspector)) => inspector.flush(self.clock.now()),
            _ => Vec::new(),
        };
        if !waiting.is_empty() {
            let layers: Vec<u32> = waiting.iter().map(|r| r.layer).collect();
            info!(
                ?layers,
                "inspection: the build ended; its last layers are inspected with the views they have"
            );
        }
        for record in &self.with_model(waiting, true) {
            self.record(record);
        }
        self.alarm.finish();
    }

    fn catch_up(&self) -> Vec<(Shot, u32, String)> {
        self.missed.clone()
    }
}

/// A view's place in the inspection and the model while its frame is processed (other lanes
/// may complete a later layer meanwhile): given up if the processing ends before it lands.
struct Flight<'s> {
    series: &'s InspectingSeries,
    inspection: Option<InFlight>,
    model: Option<ModelFlight>,
}

impl<'s> Flight<'s> {
    fn begin(series: &'s InspectingSeries, shot: Shot) -> Flight<'s> {
        let inspection = match series.inspector.lock() {
            Ok(mut inspector) => inspector.begin(shot.layer, shot.view()),
            Err(_) => None,
        };
        let model = series
            .model
            .as_ref()
            .and_then(|m| m.begin(shot.layer, shot.view()));
        Flight {
            series,
            inspection,
            model,
        }
    }
}

impl Drop for Flight<'_> {
    fn drop(&mut self) {
        let series = self.series;
        let (inspection, model) = (self.inspection.take(), self.model.take());
        if inspection.is_none() && model.is_none() {
            return;
        }
        if let (Some(flight), Some(stage)) = (model, &series.model) {
            stage.give_up(flight);
        }
        let records = match (inspection, series.inspector.lock()) {
            (Some(flight), Ok(mut inspector)) => inspector.give_up(flight, series.clock.now()),
            _ => Vec::new(),
        };
        for record in &series.with_model(records, false) {
            series.record(record);
        }
    }
}

/// The takes their series slices show, in the views the inspection uses, of every layer the
/// journal has processed views of but `inspection.jsonl` has no record of: a stop (a kill -9
/// between a layer's last slice and its record) left them uninspected. Said at WARN with the
/// layers.
fn missed_layers(
    build_dir: &Path,
    inspector: &Inspector,
    views: &[crate::shot::View],
) -> Result<Vec<(Shot, u32, String)>, super::AcquisitionError> {
    let journal = build_dir.join(crate::build_dir::JOURNAL);
    if !journal.exists() {
        return Ok(Vec::new());
    }
    let replay = crate::build_dir::Journal::read(&journal)?;
    let (layers, takes) = missed_takes(
        &replay,
        |view| inspector.needs(view),
        |layer| inspector.is_done(layer),
        views,
    );
    let (Some(first), Some(last)) = (layers.first(), layers.last()) else {
        return Ok(Vec::new());
    };
    warn!(
        layers = layers.len(),
        first,
        last,
        "inspection: {} layers were processed before the stop but never inspected (layers \
         {first} to {last}); inspecting them now",
        layers.len()
    );
    Ok(takes)
}

/// The layers `replay` has slices of in views `needs` wants but `done` has no record of, and
/// the take each of their slices shows (with `[series] take = "last"`, a retake: processing the
/// first take again would put it back in the series), with its file. Their views without a slice
/// are left to the backlog.
fn missed_takes(
    replay: &crate::build_dir::journal::Replay,
    needs: impl Fn(crate::shot::View) -> bool,
    done: impl Fn(u32) -> bool,
    views: &[crate::shot::View],
) -> (Vec<u32>, Vec<(Shot, u32, String)>) {
    let shown = |shot: &Shot| replay.slice_take(shot);
    let uninspected: std::collections::BTreeSet<u32> = replay
        .frames
        .keys()
        .filter(|shot| shown(shot) > 0 && needs(shot.view()) && !done(shot.layer))
        .map(|shot| shot.layer)
        .collect();
    let takes = uninspected
        .iter()
        .flat_map(|&layer| {
            views
                .iter()
                .map(move |view| Shot::new(layer, view.phase, view.light))
        })
        .filter(|shot| needs(shot.view()))
        .filter_map(|shot| {
            // A view with no slice yet is in the backlog already.
            let take = shown(&shot);
            let entry = replay.take_entry(&shot, take)?;
            Some((shot, take, entry.file.clone()))
        })
        .collect();
    (uninspected.into_iter().collect(), takes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::journal::{Record, Replay};
    use crate::shot::{Light, Phase, View};

    fn frame(layer: u32, light: Light, file: &str) -> Record {
        Record::Frame {
            layer,
            phase: Phase::Post,
            light,
            file: file.into(),
            bytes: 1,
            sha256: String::new(),
            at: chrono::Utc::now(),
        }
    }

    #[test]
    fn a_missed_layer_is_inspected_with_the_take_its_slices_show() {
        let now = chrono::Utc::now();
        let (top, side) = (Light::Top, Light::Side);
        let mut replay = Replay::default();
        for layer in [1, 2] {
            replay.apply(&frame(layer, top, &format!("L{layer}_top.jpg")));
            replay.apply(&frame(layer, side, &format!("L{layer}_side.jpg")));
        }
        // Layer 1: top retaken and its slice shows the retake; side processed as taken.
        replay.apply(&Record::Retake {
            layer: 1,
            phase: Phase::Post,
            light: top,
            take: 2,
            file: "L1_top.r2.jpg".into(),
            bytes: 1,
            sha256: String::new(),
            at: now,
        });
        for light in [top, side] {
            replay.apply(&Record::Processed {
                layer: 1,
                phase: Phase::Post,
                light,
                at: now,
            });
        }
        replay.apply(&Record::SliceTake {
            layer: 1,
            phase: Phase::Post,
            light: top,
            take: 2,
            at: now,
        });
        // Layer 2: only side processed; top waits in the backlog.
        replay.apply(&Record::Processed {
            layer: 2,
            phase: Phase::Post,
            light: side,
            at: now,
        });
        let views = [
            View {
                phase: Phase::Post,
                light: top,
            },
            View {
                phase: Phase::Post,
                light: side,
            },
        ];
        let (layers, takes) = missed_takes(&replay, |_| true, |_| false, &views);
        assert_eq!(layers, vec![1, 2]);
        let named: Vec<(u32, Light, u32, &str)> = takes
            .iter()
            .map(|(shot, take, file)| (shot.layer, shot.light, *take, file.as_str()))
            .collect();
        assert_eq!(
            named,
            vec![
                (1, top, 2, "L1_top.r2.jpg"),
                (1, side, 1, "L1_side.jpg"),
                (2, side, 1, "L2_side.jpg"),
            ]
        );
        let (layers, takes) = missed_takes(&replay, |_| true, |layer| layer == 1, &views);
        assert_eq!((layers, takes.len()), (vec![2], 1), "layer 1 inspected");
    }
}
