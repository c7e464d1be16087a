//! A camera body that fails on schedule, so callers' retry, reconnect and timeout paths can be
//! tested deterministically.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt;
use std::thread;
use std::time::Duration;

use crate::{Renderer, Scene};

/// A scheduled misbehaviour of one shot.
#[derive(Clone, Debug, PartialEq)]
pub enum Fault {
    /// The camera answers busy (like Nikon PTP 0x2019) to the first `times` attempts of this shot.
    Busy { times: u32 },
    /// The USB device drops at the first attempt of this shot; every call fails Disconnected until
    /// reconnect() is called.
    Disconnect,
    /// The shot takes this long (sleeps) and then succeeds.
    Slow { millis: u64 },
    /// Every attempt of this shot fails (permanent failure for that frame only).
    Fail,
    /// The call blocks (sleeps) for `millis` then fails Timeout — to test callers' timeouts.
    Hang { millis: u64 },
}

/// Identifies one shot: layer, phase ("pre"/"post"), light ("front"/"side"/"top").
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ShotKey {
    pub layer: u32,
    pub phase: String,
    pub light: String,
}

impl ShotKey {
    /// Convenience constructor: `ShotKey::new(3, "post", "top")`.
    pub fn new(layer: u32, phase: &str, light: &str) -> ShotKey {
        ShotKey {
            layer,
            phase: phase.to_owned(),
            light: light.to_owned(),
        }
    }
}

impl fmt::Display for ShotKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "L{:05}_{}_{}", self.layer, self.phase, self.light)
    }
}

/// Which shots misbehave and how (at most one fault per shot; inserting again replaces it).
#[derive(Clone, Debug, Default)]
pub struct FaultSchedule {
    faults: BTreeMap<ShotKey, Fault>,
}

impl FaultSchedule {
    /// An empty schedule: every shot succeeds.
    pub fn new() -> Self {
        Self::default()
    }

    /// Schedules `fault` for the shot `key`, replacing any earlier fault for it.
    pub fn insert(&mut self, key: ShotKey, fault: Fault) {
        self.faults.insert(key, fault);
    }

    /// The fault scheduled for `key`, if any.
    pub fn get(&self, key: &ShotKey) -> Option<&Fault> {
        self.faults.get(key)
    }

    /// Whether no fault is scheduled.
    pub fn is_empty(&self) -> bool {
        self.faults.is_empty()
    }
}

/// Why a mock capture failed; mirrors the failure classes of the real camera backend.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MockError {
    /// Transient: try again (PTP 0x2019 Device Busy).
    Busy,
    /// The device is gone until `reconnect()`.
    Disconnected,
    /// This frame cannot be taken.
    Failed(String),
    /// The camera did not answer in time.
    Timeout,
}

impl fmt::Display for MockError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MockError::Busy => f.write_str("camera busy (PTP 0x2019 Device Busy)"),
            MockError::Disconnected => f.write_str("camera disconnected"),
            MockError::Failed(why) => write!(f, "capture failed: {why}"),
            MockError::Timeout => f.write_str("camera timed out"),
        }
    }
}

impl std::error::Error for MockError {}

/// The camera body: renders on demand and applies the schedule. Keeps attempt counters per ShotKey.
pub struct MockCamera {
    renderer: Renderer,
    schedule: FaultSchedule,
    jpeg_quality: u8,
    /// `Some` when the body is set to raw: frames are D810 NEFs of the rendered picture.
    raw: Option<crate::nef::NefOptions>,
    /// Attempts of shots that have a scheduled fault (the schedule counts them).
    attempts: HashMap<ShotKey, u32>,
    /// Attempts of the latest shot without a scheduled fault: only the one being retried is
    /// kept, so a long build's history does not pile up.
    latest: Option<(ShotKey, u32)>,
    connected: bool,
    /// Shots whose Disconnect fault already fired (it fires once).
    disconnects_fired: BTreeSet<ShotKey>,
}

impl MockCamera {
    /// A connected camera rendering with `renderer`, failing per `schedule`, encoding JPEG at
    /// `jpeg_quality` (clamped to 1..=100).
    pub fn new(renderer: Renderer, schedule: FaultSchedule, jpeg_quality: u8) -> MockCamera {
        MockCamera {
            renderer,
            schedule,
            jpeg_quality,
            raw: None,
            attempts: HashMap::new(),
            latest: None,
            connected: true,
            disconnects_fired: BTreeSet::new(),
        }
    }

    /// Sets the body to raw: later frames are NEFs (see [`crate::nef`]) instead of JPEGs.
    pub fn with_raw(mut self, options: crate::nef::NefOptions) -> MockCamera {
        self.raw = Some(options);
        self
    }

    /// Capture one frame of `scene`; `key` says which shot it is (for the fault schedule).
    /// Returns JPEG bytes, or NEF bytes when set to raw. Busy/Disconnected/Failed/Timeout as
    /// scheduled. A Disconnect fault fires once (the first attempt of that shot made while
    /// connected); after reconnect() later attempts of that shot succeed. Every call counts as
    /// an attempt of `key`, including calls refused because the camera is disconnected.
    pub fn capture(&mut self, key: &ShotKey, scene: &Scene) -> Result<Vec<u8>, MockError> {
        let attempt = if self.schedule.get(key).is_some() {
            let n = self.attempts.entry(key.clone()).or_insert(0);
            *n = n.saturating_add(1);
            *n
        } else {
            match &mut self.latest {
                Some((latest, n)) if latest == key => *n = n.saturating_add(1),
                latest => *latest = Some((key.clone(), 1)),
            }
            self.latest.as_ref().map_or(1, |(_, n)| *n)
        };
        if !self.connected {
            return Err(MockError::Disconnected);
        }
        match self.schedule.get(key) {
            Some(Fault::Busy { times }) if attempt <= *times => return Err(MockError::Busy),
            Some(Fault::Disconnect) if !self.disconnects_fired.contains(key) => {
                self.disconnects_fired.insert(key.clone());
                self.connected = false;
                return Err(MockError::Disconnected);
            }
            Some(Fault::Slow { millis }) => thread::sleep(Duration::from_millis(*millis)),
            Some(Fault::Fail) => {
                return Err(MockError::Failed(format!(
                    "scheduled permanent failure of {key}"
                )))
            }
            Some(Fault::Hang { millis }) => {
                thread::sleep(Duration::from_millis(*millis));
                return Err(MockError::Timeout);
            }
            _ => {}
        }
        match &self.raw {
            Some(options) => Ok(crate::nef::encode_nef(
                &self.renderer.render(scene),
                options,
            )),
            None => self
                .renderer
                .try_render_jpeg(scene, self.jpeg_quality)
                .map_err(|e| MockError::Failed(format!("{key}: JPEG encoding: {e}"))),
        }
    }

    /// Re-opens the (mock) USB device. Always succeeds.
    pub fn reconnect(&mut self) -> Result<(), MockError> {
        self.connected = true;
        Ok(())
    }

    /// Whether the device is attached (false after a Disconnect fault until `reconnect()`).
    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// How many times `capture` was called for `key`: every call for a shot with a scheduled
    /// fault; for any other shot, its latest run of consecutive calls (0 once another shot came).
    pub fn attempts(&self, key: &ShotKey) -> u32 {
        match (&self.latest, self.attempts.get(key)) {
            (_, Some(&n)) => n,
            (Some((latest, n)), None) if latest == key => *n,
            _ => 0,
        }
    }

    /// The anomalies the next frames show (see [`crate::Defect`]).
    pub fn set_defects(&mut self, defects: Vec<crate::Defect>) {
        self.renderer.defects = defects;
    }

    /// The renderer, e.g. for its ground-truth homography.
    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use super::*;
    use crate::{demo_parts, Homography, Illumination, Shape};

    const W: u32 = 240;
    const H: u32 = 160;

    fn camera(schedule: FaultSchedule) -> MockCamera {
        MockCamera::new(
            Renderer::new(W, H, Homography::oblique_view(W, H)),
            schedule,
            90,
        )
    }

    fn scene(parts: &[Shape]) -> Scene<'_> {
        Scene {
            layer: 5,
            fused: parts,
            scanned: true,
            illumination: Illumination::Top,
        }
    }

    fn decodes(bytes: &[u8]) {
        let img = image::load_from_memory(bytes).expect("valid JPEG");
        assert_eq!((img.width(), img.height()), (W, H));
    }

    #[test]
    fn no_fault_succeeds_and_jpeg_decodes() {
        let mut cam = camera(FaultSchedule::new());
        let parts = demo_parts(5);
        let key = ShotKey::new(5, "post", "top");
        let bytes = cam.capture(&key, &scene(&parts)).expect("no fault");
        decodes(&bytes);
        assert_eq!(cam.attempts(&key), 1);
        assert_eq!(cam.attempts(&ShotKey::new(5, "pre", "top")), 0);
    }

    #[test]
    fn busy_three_times_then_ok() {
        let key = ShotKey::new(2, "pre", "front");
        let mut schedule = FaultSchedule::new();
        schedule.insert(key.clone(), Fault::Busy { times: 3 });
        assert!(!schedule.is_empty());
        assert_eq!(schedule.get(&key), Some(&Fault::Busy { times: 3 }));
        let mut cam = camera(schedule);
        let parts = demo_parts(2);
        for i in 1..=3 {
            assert_eq!(cam.capture(&key, &scene(&parts)), Err(MockError::Busy));
            assert_eq!(cam.attempts(&key), i);
        }
        decodes(
            &cam.capture(&key, &scene(&parts))
                .expect("fourth attempt succeeds"),
        );
        assert_eq!(cam.attempts(&key), 4);
        // Other shots are unaffected.
        let other = ShotKey::new(2, "pre", "side");
        assert!(cam.capture(&other, &scene(&parts)).is_ok());
    }

    #[test]
    fn disconnect_until_reconnect() {
        let key = ShotKey::new(9, "post", "side");
        let other = ShotKey::new(9, "post", "top");
        let mut schedule = FaultSchedule::new();
        schedule.insert(key.clone(), Fault::Disconnect);
        let mut cam = camera(schedule);
        let parts = demo_parts(9);
        assert!(cam.is_connected());
        assert_eq!(
            cam.capture(&key, &scene(&parts)),
            Err(MockError::Disconnected)
        );
        assert!(!cam.is_connected());
        assert_eq!(
            cam.capture(&key, &scene(&parts)),
            Err(MockError::Disconnected)
        );
        assert_eq!(
            cam.capture(&other, &scene(&parts)),
            Err(MockError::Disconnected)
        );
        assert_eq!(cam.reconnect(), Ok(()));
        assert!(cam.is_connected());
        decodes(&cam.capture(&key, &scene(&parts)).expect("fires once"));
        assert!(cam.capture(&other, &scene(&parts)).is_ok());
        assert_eq!(cam.attempts(&key), 3);
    }

    #[test]
    fn fail_is_permanent_for_that_frame() {
        let key = ShotKey::new(1, "post", "front");
        let mut schedule = FaultSchedule::new();
        schedule.insert(key.clone(), Fault::Fail);
        let mut cam = camera(schedule);
        let parts = demo_parts(1);
        for _ in 0..5 {
            match cam.capture(&key, &scene(&parts)) {
                Err(MockError::Failed(why)) => assert!(why.contains("L00001_post_front"), "{why}"),
                other => panic!("expected Failed, got {:?}", other.map(|b| b.len())),
            }
        }
        assert_eq!(cam.attempts(&key), 5);
        assert!(cam.is_connected());
        assert!(cam
            .capture(&ShotKey::new(2, "post", "front"), &scene(&parts))
            .is_ok());
    }

    #[test]
    fn slow_adds_latency_then_succeeds() {
        let key = ShotKey::new(4, "pre", "top");
        let mut schedule = FaultSchedule::new();
        schedule.insert(key.clone(), Fault::Slow { millis: 120 });
        let mut cam = camera(schedule);
        let parts = demo_parts(4);
        let t = Instant::now();
        decodes(&cam.capture(&key, &scene(&parts)).expect("slow but ok"));
        assert!(
            t.elapsed() >= Duration::from_millis(120),
            "{:?}",
            t.elapsed()
        );
    }

    #[test]
    fn hang_blocks_then_times_out() {
        let key = ShotKey::new(4, "post", "top");
        let mut schedule = FaultSchedule::new();
        schedule.insert(key.clone(), Fault::Hang { millis: 80 });
        let mut cam = camera(schedule);
        let parts = demo_parts(4);
        let t = Instant::now();
        assert_eq!(cam.capture(&key, &scene(&parts)), Err(MockError::Timeout));
        assert!(t.elapsed() >= Duration::from_millis(80));
        assert_eq!(cam.capture(&key, &scene(&parts)), Err(MockError::Timeout));
    }

    #[test]
    fn errors_display_and_keys_order() {
        assert_eq!(MockError::Timeout.to_string(), "camera timed out");
        assert!(MockError::Failed("x".into()).to_string().contains('x'));
        let e: Box<dyn std::error::Error> = Box::new(MockError::Busy);
        assert!(e.to_string().contains("busy"));
        assert!(ShotKey::new(1, "post", "top") < ShotKey::new(2, "pre", "front"));
        assert_eq!(
            ShotKey::new(12, "pre", "side").to_string(),
            "L00012_pre_side"
        );
    }

    #[test]
    fn renderer_is_exposed() {
        let cam = camera(FaultSchedule::new());
        assert_eq!(cam.renderer().width, W);
        assert_eq!(cam.renderer().homography, Homography::oblique_view(W, H));
    }
}
