//! The operator's one line per layer signal: the processing worker counts each frame of a
//! layer's phase as it ends, and the layer's line is logged once all its frames have.

use crate::shot::{Flights, Light, Phase, Shot};
use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;
use tracing::info;

/// The processing of one layer's phases, for the operator's one line per layer signal.
pub(super) struct Tally {
    frames: usize,
    failed: usize,
    /// The lights whose frame was left for a catch-up (the disk full at its slice's write) or
    /// the next start (concluding it panicked) and is not processed yet: counted for the layer's
    /// line once caught up while it is open, else told in a line of its own.
    deferred: BTreeSet<Light>,
    /// From the start of its first frame's processing to the end of its last.
    first_start: Duration,
    last_end: Duration,
    /// From the last frame's hand-over to the end of its processing (none for a catch-up).
    lag: Option<Duration>,
}

impl Tally {
    /// No frame counted yet (its times are set by the first).
    fn empty() -> Tally {
        Tally {
            frames: 0,
            failed: 0,
            deferred: BTreeSet::new(),
            first_start: Duration::MAX,
            last_end: Duration::ZERO,
            lag: None,
        }
    }
}

/// The layers being processed (frames come in build order, one per lane at a time): a layer's
/// line is logged once all its frames are processed, or, a frame missing, once a later layer's
/// are (unless a frame of it is still being processed on another lane) or the worker stops.
/// Lines come in build order.
pub(super) struct LayerTally {
    /// The frames of one signal (the lights of a phase).
    complete: usize,
    open: BTreeMap<(u32, Phase), Tally>,
    /// Frames being processed ([`LayerTally::begin`]) and not counted yet.
    in_flight: Flights<(u32, Phase)>,
}

impl LayerTally {
    pub(super) fn new(complete: usize) -> LayerTally {
        LayerTally {
            complete: complete.max(1),
            open: Default::default(),
            in_flight: Default::default(),
        }
    }

    /// A frame's processing starts: no line from its layer's on is logged before it is counted
    /// ([`LayerTally::add`]) or forgotten ([`LayerTally::forget`]).
    pub(super) fn begin(&mut self, shot: &Shot) {
        self.in_flight.begin((shot.layer, shot.phase));
    }

    /// A frame that began and is left for a catch-up (the disk was full at its slice's write)
    /// or the next start (concluding it panicked): counted as deferred; returns the layers this lets
    /// go.
    pub(super) fn forget(&mut self, shot: &Shot) -> Vec<((u32, Phase), Tally)> {
        let key = (shot.layer, shot.phase);
        self.in_flight.land(key);
        let tally = self.open.entry(key).or_insert_with(Tally::empty);
        tally.deferred.insert(shot.light);
        self.ready()
    }

    /// The open layers up to the last complete one (each of its frames processed or deferred),
    /// in build order, but none from the first with a frame in flight on.
    fn ready(&mut self) -> Vec<((u32, Phase), Tally)> {
        let complete = self.complete;
        self.in_flight
            .release(&mut self.open, |t| t.frames + t.deferred.len() >= complete)
    }

    /// Counts one frame processed (`ok`: its slice written) between `start` and `end`; returns
    /// the layers now done, in build order.
    pub(super) fn add(
        &mut self,
        shot: &Shot,
        ok: bool,
        (start, end): (Duration, Duration),
        lag: Option<Duration>,
    ) -> Vec<((u32, Phase), Tally)> {
        let key = (shot.layer, shot.phase);
        self.in_flight.land(key);
        let tally = self.open.entry(key).or_insert_with(Tally::empty);
        // A deferred frame caught up while its layer is open is one of its frames now.
        tally.deferred.remove(&shot.light);
        tally.frames += 1;
        tally.failed += usize::from(!ok);
        tally.first_start = tally.first_start.min(start);
        tally.last_end = tally.last_end.max(end);
        tally.lag = lag;
        self.ready()
    }

    /// The layers whose line is not logged yet, in build order.
    #[cfg(test)]
    pub(super) fn open_layers(&self) -> Vec<(u32, Phase)> {
        self.open.keys().copied().collect()
    }

    /// Every layer still open, in build order.
    pub(super) fn flush(&mut self) -> Vec<((u32, Phase), Tally)> {
        std::mem::take(&mut self.open).into_iter().collect()
    }
}

/// The operator's line for each layer signal's frames processed.
pub(super) fn log_layers(layers: Vec<((u32, Phase), Tally)>, backlog: usize) {
    for (key, tally) in layers {
        log_layer(key, &tally, backlog);
    }
}

fn log_layer((layer, phase): (u32, Phase), tally: &Tally, backlog: usize) {
    let processing_ms = tally.last_end.saturating_sub(tally.first_start).as_millis() as u64;
    let lag = match tally.lag {
        Some(lag) => lag.as_millis().to_string(),
        None if tally.frames == 0 => "-".to_string(),
        None => "catch-up".to_string(),
    };
    info!(
        layer,
        phase = %phase,
        frames = tally.frames,
        failed = tally.failed,
        deferred = tally.deferred.len(),
        processing_ms,
        lag_ms = %lag,
        backlog,
        "layer processed"
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shot::Light;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn a_layer_line_comes_once_its_frames_are_processed_and_a_missing_frame_does_not_hold_it() {
        let mut tally = LayerTally::new(3);
        let lights = [Light::Front, Light::Side, Light::Top];
        // Layer 1 pre: two frames, nothing yet; the third completes it.
        for (i, light) in lights[..2].iter().enumerate() {
            let at = ms(10 * i as u64);
            assert!(tally
                .add(
                    &Shot::new(1, Phase::Pre, *light),
                    true,
                    (at, at + ms(5)),
                    Some(ms(7))
                )
                .is_empty());
        }
        let done = tally.add(
            &Shot::new(1, Phase::Pre, Light::Top),
            false,
            (ms(20), ms(40)),
            None,
        );
        assert_eq!(done.len(), 1);
        let ((layer, phase), t) = &done[0];
        assert_eq!((*layer, *phase, t.frames, t.failed), (1, Phase::Pre, 3, 1));
        assert_eq!(
            t.last_end - t.first_start,
            ms(40),
            "from the first start to the last end"
        );
        assert_eq!(t.lag, None, "the last frame's lag (a catch-up has none)");
        // Layer 1 post misses its top frame; layer 2 pre's frames come in between, processed
        // two at a time: layer 1 post is told (2 frames) just before layer 2 pre.
        tally.add(
            &Shot::new(1, Phase::Post, Light::Front),
            true,
            (ms(50), ms(60)),
            Some(ms(10)),
        );
        tally.add(
            &Shot::new(2, Phase::Pre, Light::Front),
            true,
            (ms(55), ms(65)),
            Some(ms(10)),
        );
        tally.add(
            &Shot::new(1, Phase::Post, Light::Side),
            true,
            (ms(60), ms(70)),
            Some(ms(10)),
        );
        tally.add(
            &Shot::new(2, Phase::Pre, Light::Side),
            true,
            (ms(65), ms(75)),
            Some(ms(10)),
        );
        let done = tally.add(
            &Shot::new(2, Phase::Pre, Light::Top),
            true,
            (ms(75), ms(85)),
            Some(ms(9)),
        );
        let told: Vec<_> = done.iter().map(|(k, t)| (*k, t.frames)).collect();
        assert_eq!(told, vec![((1, Phase::Post), 2), ((2, Phase::Pre), 3)]);
        // A layer left open when the worker stops is told then.
        tally.add(
            &Shot::new(2, Phase::Post, Light::Front),
            true,
            (ms(90), ms(95)),
            Some(ms(5)),
        );
        let rest: Vec<_> = tally.flush().iter().map(|(k, t)| (*k, t.frames)).collect();
        assert_eq!(rest, vec![((2, Phase::Post), 1)]);
        assert!(tally.flush().is_empty());
    }

    #[test]
    fn a_layer_line_waits_for_its_frame_on_another_lane_and_lines_stay_in_build_order() {
        let lights = [Light::Front, Light::Side, Light::Top];
        for counted in [true, false] {
            let mut tally = LayerTally::new(3);
            let at = (ms(0), ms(1));
            for light in &lights[..2] {
                tally.add(&Shot::new(1, Phase::Post, *light), true, at, None);
            }
            // Layer 1 post's last frame is on one lane while three lanes finish layer 2 pre.
            let late = Shot::new(1, Phase::Post, Light::Top);
            tally.begin(&late);
            for light in lights {
                let shot = Shot::new(2, Phase::Pre, light);
                tally.begin(&shot);
                let told = tally.add(&shot, true, at, None);
                assert!(
                    told.is_empty(),
                    "{:?}",
                    told.iter().map(|t| t.0).collect::<Vec<_>>()
                );
            }
            let told = if counted {
                tally.add(&late, true, at, None)
            } else {
                tally.forget(&late)
            };
            let told: Vec<_> = told
                .iter()
                .map(|(k, t)| (*k, t.frames, t.deferred.len()))
                .collect();
            let first = if counted { (3, 0) } else { (2, 1) };
            assert_eq!(
                told,
                vec![
                    ((1, Phase::Post), first.0, first.1),
                    ((2, Phase::Pre), 3, 0)
                ]
            );
            assert!(tally.flush().is_empty());
        }
    }

    #[test]
    fn a_deferred_frame_caught_up_while_its_layer_is_open_is_counted_once() {
        let [a, b, c] =
            [Light::Front, Light::Side, Light::Top].map(|l| Shot::new(1, Phase::Post, l));
        let at = (ms(0), ms(1));
        let mut tally = LayerTally::new(3);
        tally.add(&a, true, at, None);
        // B's slice found the disk full, twice (the first take and a catch-up): one deferred.
        for _ in 0..2 {
            tally.begin(&b);
            assert!(tally.forget(&b).is_empty());
        }
        // Caught up while the layer waits for C: one of its frames now, not a deferred one too.
        tally.begin(&b);
        assert!(
            tally.add(&b, true, at, None).is_empty(),
            "C is still to come"
        );
        let told = tally.add(&c, true, at, None);
        let told: Vec<_> = told
            .iter()
            .map(|(k, t)| (*k, t.frames, t.deferred.len()))
            .collect();
        assert_eq!(told, vec![((1, Phase::Post), 3, 0)]);
        assert!(tally.flush().is_empty());
    }
}
