//! The trained model in the processing worker (`[inspection.model]`): every view it looks at
//! is classified tile by tile as soon as it is rectified (in the model's own threads); a
//! layer's inspection record waits here until the model has seen that layer's views (or a later
//! layer's arrive while none of this layer's is still being processed on another lane), then
//! gets the model's flags after the classical ones, and each view's heat map is written to
//! `model/<view>/L00042.png` for the page.

use crate::build_dir::inspection::InspectionRecord;
use crate::learn::live::{heatmap_path, heatmap_png, LiveModel, ViewScan};
use crate::logging::Chain;
use crate::rectify::FrameLuma;
use crate::shot::View;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use tracing::{info, warn};

/// The model's part of the live inspection.
pub struct ModelStage {
    live: LiveModel,
    grid: crate::geometry::Grid,
    wanted: BTreeSet<View>,
    build_dir: PathBuf,
    fsync: bool,
    state: Mutex<State>,
}

#[derive(Default)]
struct State {
    /// Per layer, the newest scan of each view: a view processed again (a retake the series
    /// shows, a frame caught up after a pause) replaces its scan rather than counting twice.
    scans: BTreeMap<u32, BTreeMap<View, ViewScan>>,
    waiting: BTreeMap<u32, InspectionRecord>,
    /// Views being processed, per layer ([`ModelStage::begin`]).
    in_flight: crate::shot::Flights<u32>,
}

/// A view of a layer being processed that the model will look at: the layer's record waits for
/// its scan ([`ModelStage::scan`]) or for it to be given up ([`ModelStage::give_up`]).
#[must_use = "a view in flight holds back the records until it is scanned or given up"]
#[derive(Debug)]
pub struct ModelFlight {
    layer: u32,
}

impl ModelStage {
    /// The stage for a checked model, over views on `grid` of the configured `views`.
    pub fn new(
        live: LiveModel,
        grid: crate::geometry::Grid,
        views: &[View],
        build_dir: &Path,
        fsync: bool,
    ) -> ModelStage {
        let wanted = views.iter().copied().filter(|v| live.wants(*v)).collect();
        let h = &live.model.header;
        info!(
            model = %live.model.path.display(),
            classes = ?h.classes,
            validation_accuracy = h.validation.accuracy,
            "inspection: the model runs on every layer after the classical checks"
        );
        ModelStage {
            live,
            grid,
            wanted,
            build_dir: build_dir.to_path_buf(),
            fsync,
            state: Mutex::new(State::default()),
        }
    }

    /// Says that a view of `layer` is being processed, for [`ModelStage::scan`]; `None` if the
    /// model does not look at it.
    pub fn begin(&self, layer: u32, view: View) -> Option<ModelFlight> {
        if !self.wanted.contains(&view) {
            return None;
        }
        let mut s = self.state.lock().ok()?;
        s.in_flight.begin(layer);
        Some(ModelFlight { layer })
    }

    /// A view in flight whose processing failed before it could be scanned.
    pub fn give_up(&self, flight: ModelFlight) {
        if let Ok(mut s) = self.state.lock() {
            s.in_flight.land(flight.layer);
        }
    }

    /// Classifies a rectified view of `layer` (when the model looks at it); `flight` is its
    /// [`ModelStage::begin`], landed with the scan.
    pub fn scan(&self, layer: u32, view: View, luma: &FrameLuma, flight: Option<ModelFlight>) {
        if !self.wanted.contains(&view) {
            if let Some(flight) = flight {
                self.give_up(flight);
            }
            return;
        }
        let scanned = self.live.install(|| {
            let cells =
                crate::inspect::cells::Cells::from_luma(luma, &self.grid, self.live.cell_px());
            self.live.scan_cells(
                view,
                (cells.rows, cells.cols),
                &cells.mean,
                &cells.texture,
                &self.grid,
            )
        });
        match scanned {
            Ok(scan) => {
                if let Some(png) = heatmap_png(&scan) {
                    let path = heatmap_path(&self.build_dir, &view.to_string(), layer);
                    let written = path
                        .parent()
                        .map_or(Ok(()), std::fs::create_dir_all)
                        .map_err(|e| e.to_string())
                        .and_then(|_| {
                            crate::fsutil::write_atomic(&path, &png, self.fsync)
                                .map_err(|e| crate::logging::chain(&e))
                        });
                    if let Err(e) = written {
                        warn!(layer, view = %view, error = %e, "model: cannot write the heat map");
                    }
                }
                if let Ok(mut s) = self.state.lock() {
                    s.add(layer, scan);
                    if let Some(flight) = flight {
                        s.in_flight.land(flight.layer);
                    }
                }
            }
            Err(e) => {
                warn!(layer, view = %view, error = %Chain(&e), "model: cannot classify the view");
                if let Some(flight) = flight {
                    self.give_up(flight);
                }
            }
        }
    }

    /// Takes the classical records; returns the records that are complete, model flags added,
    /// in layer order: a complete record waits behind an earlier one that is not. `flush`
    /// completes every record waiting.
    pub fn complete(&self, records: Vec<InspectionRecord>, flush: bool) -> Vec<InspectionRecord> {
        let Ok(mut s) = self.state.lock() else {
            return records;
        };
        for r in records {
            s.waiting.insert(r.layer, r);
        }
        let ready = s.ready(self.wanted.len(), flush);
        let mut out = Vec::new();
        for layer in ready {
            let Some(mut record) = s.waiting.remove(&layer) else {
                continue;
            };
            let scans = s.scans.remove(&layer).unwrap_or_default();
            let ms: f64 = scans.values().map(|v| v.ms).sum();
            for scan in scans.values() {
                record.flags.extend(self.live.flags(scan, &self.grid));
            }
            record.plate.insert("model_ms".into(), ms);
            record
                .plate
                .insert("model_views".into(), scans.len() as f64);
            out.push(record);
        }
        // Scans of layers that never got a record (not inspected) are dropped once passed.
        let newest = s.scans.keys().next_back().copied().unwrap_or(0);
        let oldest_waiting = s.waiting.keys().next().copied().unwrap_or(u32::MAX);
        s.scans
            .retain(|l, _| *l + 2 >= newest || *l >= oldest_waiting);
        out
    }
}

impl State {
    /// A view's scan of `layer`, in place of any earlier one of that view.
    fn add(&mut self, layer: u32, scan: ViewScan) {
        self.scans.entry(layer).or_default().insert(scan.view, scan);
    }

    /// The waiting layers whose records are complete, in order, up to the first that is not:
    /// the model has scanned its `wanted` views, or a later layer's scans arrived while none of
    /// its views is still in flight (or `flush`).
    fn ready(&self, wanted: usize, flush: bool) -> Vec<u32> {
        let newest = self.scans.keys().next_back().copied().unwrap_or(0);
        self.waiting
            .keys()
            .copied()
            .take_while(|l| {
                flush
                    || (*l < newest && !self.in_flight.holds(*l))
                    || self.scans.get(l).map_or(0, |v| v.len()) >= wanted
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::inspection::tests::record_with;
    use crate::shot::{Light, Phase};

    fn scan_of(view: View) -> ViewScan {
        ViewScan {
            view,
            rows: 0,
            cols: 0,
            defect: Vec::new(),
            best: Vec::new(),
            tile_mm: 1.0,
            ms: 0.0,
        }
    }

    fn view(light: Light) -> View {
        View {
            phase: Phase::Post,
            light,
        }
    }

    fn add(s: &mut State, layer: u32, view: View) {
        s.add(layer, scan_of(view));
    }

    #[test]
    fn a_complete_record_waits_behind_an_earlier_one_still_in_flight() {
        let mut s = State::default();
        s.waiting.insert(5, record_with(5, vec![]));
        s.waiting.insert(6, record_with(6, vec![]));
        s.in_flight.begin(5);
        add(&mut s, 6, view(Light::Top));
        assert_eq!(
            s.ready(1, false),
            Vec::<u32>::new(),
            "5 is held, so 6 waits"
        );
        s.in_flight.land(5);
        assert_eq!(s.ready(1, false), vec![5, 6]);
        s.in_flight.begin(5);
        assert_eq!(s.ready(2, true), vec![5, 6], "flush takes every record");
    }

    #[test]
    fn a_view_scanned_twice_counts_once_and_its_newest_scan_is_kept() {
        let mut s = State::default();
        s.waiting.insert(5, record_with(5, vec![]));
        add(&mut s, 5, view(Light::Top));
        // The same view again (a retake the series shows, or a frame caught up after a pause).
        let mut again = scan_of(view(Light::Top));
        again.ms = 7.0;
        s.add(5, again);
        assert_eq!(
            s.ready(2, false),
            Vec::<u32>::new(),
            "one view of two wanted: the record waits for the other"
        );
        assert_eq!(s.scans[&5].len(), 1);
        assert_eq!(s.scans[&5][&view(Light::Top)].ms, 7.0, "the newest scan");
        add(&mut s, 5, view(Light::Side));
        assert_eq!(s.ready(2, false), vec![5]);
    }
}
