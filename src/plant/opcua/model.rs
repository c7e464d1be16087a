//! What the daemon reports, written into the address space ([`super::space`]): one task reads
//! the plant feed and sets values (subscribers are notified by the server), adds the nodes of
//! parts, plate values and health entries as they first appear, and raises the inspection
//! alarm's condition events.

use super::nodes::{AlarmShared, Manager};
use super::space::{self, id, ALARM, HEALTH, JOB, PARTS, PLATE, PROCESS};
use crate::build_dir::alarm::{AlarmEvent, AlarmState};
use crate::build_dir::inspection::{InspectionRecord, Severity};
use crate::plant::event::{BuildInfo, PlantEvent, PlantStatus};
use chrono::{DateTime, Utc};
use opcua::core_namespace::events::AlarmConditionType;
use opcua::nodes::NamespaceMap;
use opcua::server::SubscriptionCache;
use opcua::types::{ByteString, DataValue, LocalizedText, NodeId, ObjectId, Variant};
use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use tracing::warn;

/// Where the feed's events go.
pub struct Model {
    manager: Arc<Manager>,
    subscriptions: Arc<SubscriptionCache>,
    ns: u16,
    alarm: Arc<Mutex<AlarmShared>>,
    /// The parts, plate metrics and health entries that have nodes.
    parts: BTreeSet<i64>,
    plate: BTreeSet<String>,
    health: BTreeSet<String>,
    /// Flags at warning and at critical, and layers inspected, since the server started.
    warnings: u32,
    criticals: u32,
    inspected: u32,
    /// Condition events raised (their ids are unique with it).
    events: u64,
}

fn time(at: DateTime<Utc>) -> opcua::types::DateTime {
    opcua::types::DateTime::from(at)
}

/// A name fit for a node id and browse name: letters, digits and `_`.
fn node_name(name: &str) -> String {
    name.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

impl Model {
    pub fn new(
        manager: Arc<Manager>,
        subscriptions: Arc<SubscriptionCache>,
        ns: u16,
        alarm: Arc<Mutex<AlarmShared>>,
    ) -> Model {
        Model {
            manager,
            subscriptions,
            ns,
            alarm,
            parts: BTreeSet::new(),
            plate: BTreeSet::new(),
            health: BTreeSet::new(),
            warnings: 0,
            criticals: 0,
            inspected: 0,
            events: 0,
        }
    }

    /// Sets each path's value (subscribers are notified of the changes).
    fn set(&self, values: Vec<(String, Variant)>) {
        let ids: Vec<NodeId> = values.iter().map(|(path, _)| id(self.ns, path)).collect();
        let result = self.manager.set_values(
            &self.subscriptions,
            ids.iter()
                .zip(values)
                .map(|(id, (_, value))| (id, None, DataValue::new_now(value))),
        );
        if let Err(status) = result {
            warn!(%status, "OPC UA: a value could not be set");
        }
    }

    /// Adds the variables of `names` under `parent` that are not there yet.
    fn ensure(&self, parent: &str, names: &[(&str, Variant)]) {
        let space = self.manager.address_space();
        let mut space = space.write();
        for (name, value) in names {
            let path = format!("{parent}.{name}");
            if space.find(&id(self.ns, &path)).is_none() {
                space::variable(
                    &mut space,
                    self.ns,
                    &path,
                    id(self.ns, parent),
                    value.clone(),
                );
            }
        }
    }

    fn ensure_object(&self, path: &str, parent: &str) {
        let space = self.manager.address_space();
        let mut space = space.write();
        if space.find(&id(self.ns, path)).is_none() {
            space::object(&mut space, self.ns, path, id(self.ns, parent), false);
        }
    }

    pub fn apply(&mut self, event: &PlantEvent) {
        match event {
            PlantEvent::BuildStarted(info) => self.started(info),
            PlantEvent::FrameStored(_) | PlantEvent::FrameMissing { .. } => {}
            PlantEvent::PhaseDone {
                layer,
                phase,
                signal_at,
                ..
            } => self.set(vec![
                (format!("{PROCESS}.CurrentLayer"), Variant::from(*layer)),
                (format!("{PROCESS}.Phase"), Variant::from(phase.to_string())),
                (
                    format!("{PROCESS}.LastSignalTime"),
                    Variant::from(time(*signal_at)),
                ),
            ]),
            PlantEvent::Inspected(record) => self.inspected(record),
            PlantEvent::Alarm(alarm) => self.alarm(alarm),
            PlantEvent::BuildEnded {
                completed,
                failed,
                at,
                ..
            } => {
                let state = match (completed, failed) {
                    (true, _) => "Ended",
                    (false, true) => "Failed",
                    (false, false) => "Stopped",
                };
                self.set(vec![
                    (format!("{JOB}.State"), Variant::from(state)),
                    (format!("{JOB}.EndTime"), Variant::from(time(*at))),
                ]);
            }
        }
    }

    fn started(&mut self, info: &BuildInfo) {
        self.alarm
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .build_dir = Some(info.dir.clone());
        self.set(vec![
            (format!("{JOB}.Name"), Variant::from(info.name.as_str())),
            (format!("{JOB}.Identifier"), Variant::from(info.id.as_str())),
            (
                format!("{JOB}.Program"),
                Variant::from(info.program.clone().unwrap_or_default()),
            ),
            (format!("{JOB}.State"), Variant::from("Running")),
            (format!("{JOB}.StartTime"), Variant::from(time(info.at))),
            (
                format!("{JOB}.EndTime"),
                Variant::from(opcua::types::DateTime::null()),
            ),
            (
                format!("{JOB}.LayersExpected"),
                Variant::from(info.layers_expected.unwrap_or(0)),
            ),
        ]);
        // A restart in the middle of a raise: the alarm is still waiting. The history keeps no
        // severity; a raise is at the alarm's, critical by default.
        if let Some(AlarmState::Raised {
            layer,
            kind,
            at,
            message,
        }) = &info.alarm
        {
            self.raise(*layer, &kind.to_string(), Severity::Critical, message, *at);
        }
    }

    fn inspected(&mut self, record: &InspectionRecord) {
        self.inspected += 1;
        let warnings = record
            .flags
            .iter()
            .filter(|f| f.severity == Severity::Warning)
            .count() as u32;
        let criticals = record
            .flags
            .iter()
            .filter(|f| f.severity == Severity::Critical)
            .count() as u32;
        self.warnings += warnings;
        self.criticals += criticals;
        let mut values = vec![
            (
                format!("{PROCESS}.LayersInspected"),
                Variant::from(self.inspected),
            ),
            (
                format!("{PLATE}.FlagsOnLastLayer"),
                Variant::from(record.flags.len() as u32),
            ),
            (
                format!("{PLATE}.WarningFlagsTotal"),
                Variant::from(self.warnings),
            ),
            (
                format!("{PLATE}.CriticalFlagsTotal"),
                Variant::from(self.criticals),
            ),
        ];
        for (name, value) in &record.plate {
            let name = node_name(name);
            if self.plate.len() < 256 && self.plate.insert(name.clone()) {
                self.ensure(PLATE, &[(&name, Variant::from(f64::NAN))]);
            }
            if self.plate.contains(&name) {
                values.push((format!("{PLATE}.{name}"), Variant::from(*value)));
            }
        }
        for part in &record.parts {
            let path = format!("{PARTS}.Part{}", part.part);
            if !self.parts.contains(&part.part) {
                if self.parts.len() >= 1024 {
                    continue;
                }
                self.parts.insert(part.part);
                self.ensure_object(&path, PARTS);
                let names: Vec<(&str, Variant)> = PART_VALUES
                    .iter()
                    .map(|n| (*n, Variant::from(f64::NAN)))
                    .chain([("Flags", Variant::from(0u32))])
                    .collect();
                self.ensure(&path, &names);
            }
            let flags = record
                .flags
                .iter()
                .filter(|f| f.part == Some(part.part))
                .count() as u32;
            let number = |v: Option<f64>| Variant::from(v.unwrap_or(f64::NAN));
            for (name, value) in PART_VALUES.iter().zip([
                part.area_ratio,
                part.iou,
                part.unfused.unwrap_or(f64::NAN),
                part.fused_fraction,
                part.post_mean,
            ]) {
                values.push((format!("{path}.{name}"), number(Some(value))));
            }
            values.push((format!("{path}.Flags"), Variant::from(flags)));
        }
        self.set(values);
    }

    /// The daemon's latest status: its state and the health of its parts.
    pub fn status(&mut self, status: &PlantStatus) {
        let mut values = vec![(
            format!("{HEALTH}.DaemonState"),
            Variant::from(status.state.as_str()),
        )];
        for (name, health) in &status.health {
            let node = node_name(name);
            let path = format!("{HEALTH}.{node}");
            if !self.health.contains(&node) {
                if self.health.len() >= 64 {
                    continue;
                }
                self.health.insert(node.clone());
                self.ensure_object(&path, HEALTH);
                self.ensure(
                    &path,
                    &[
                        ("State", Variant::from("")),
                        ("Summary", Variant::from("")),
                        ("Warning", Variant::from("")),
                    ],
                );
            }
            values.push((
                format!("{path}.State"),
                Variant::from(health.state.to_string()),
            ));
            values.push((
                format!("{path}.Summary"),
                Variant::from(health.summary.as_str()),
            ));
            values.push((
                format!("{path}.Warning"),
                Variant::from(health.warning.clone().unwrap_or_default()),
            ));
        }
        if let Some(layer) = status.layer {
            values.push((format!("{PROCESS}.CurrentLayer"), Variant::from(layer)));
        }
        if let Some(phase) = status.phase {
            values.push((format!("{PROCESS}.Phase"), Variant::from(phase.to_string())));
        }
        self.set(values);
    }

    fn alarm(&mut self, event: &AlarmEvent) {
        match event {
            AlarmEvent::Raised {
                at,
                layer,
                kind,
                severity,
                message,
            } => self.raise(*layer, &kind.to_string(), *severity, message, *at),
            AlarmEvent::Acknowledged { at, by, note } => {
                self.acknowledged(by, note.as_deref(), *at)
            }
            AlarmEvent::Cleared { at, .. } => {
                self.alarm.lock().unwrap_or_else(|e| e.into_inner()).pending = None;
                self.set(vec![(format!("{ALARM}.Active"), Variant::from(false))]);
                self.condition(
                    false,
                    true,
                    100,
                    "inspection alarm cleared by a clean layer",
                    *at,
                );
            }
        }
    }

    fn raise(
        &mut self,
        layer: u32,
        kind: &str,
        severity: Severity,
        message: &str,
        at: DateTime<Utc>,
    ) {
        let weight = if severity >= Severity::Critical {
            900
        } else {
            500
        };
        let text = format!("layer {layer}: {kind}: {message}");
        let event_id = self.condition(true, false, weight, &text, at);
        {
            let mut alarm = self.alarm.lock().unwrap_or_else(|e| e.into_inner());
            alarm.pending = Some(event_id.clone());
            alarm.raise = Some(crate::build_dir::alarm::SeenRaise {
                layer,
                at: Some(at),
            });
        }
        self.set(vec![
            (format!("{ALARM}.Active"), Variant::from(true)),
            (format!("{ALARM}.Acknowledged"), Variant::from(false)),
            (format!("{ALARM}.Layer"), Variant::from(layer)),
            (format!("{ALARM}.Kind"), Variant::from(kind)),
            (format!("{ALARM}.Message"), Variant::from(message)),
            (format!("{ALARM}.AcknowledgedBy"), Variant::from("")),
            (format!("{ALARM}.LastEventId"), Variant::from(event_id)),
        ]);
    }

    /// An acknowledgement (from any client, the page or the CLI), once per raise.
    pub fn acknowledged(&mut self, by: &str, note: Option<&str>, at: DateTime<Utc>) {
        let was_pending = self
            .alarm
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pending
            .take()
            .is_some();
        if !was_pending {
            return;
        }
        let text = match note {
            Some(note) => format!("inspection alarm acknowledged by {by}: {note}"),
            None => format!("inspection alarm acknowledged by {by}"),
        };
        let event_id = self.condition(true, true, 500, &text, at);
        self.set(vec![
            (format!("{ALARM}.Acknowledged"), Variant::from(true)),
            (format!("{ALARM}.AcknowledgedBy"), Variant::from(by)),
            (format!("{ALARM}.LastEventId"), Variant::from(event_id)),
        ]);
    }

    /// Raises an AlarmConditionType event for the inspection alarm's state; returns its id.
    fn condition(
        &mut self,
        active: bool,
        acked: bool,
        severity: u16,
        message: &str,
        at: DateTime<Utc>,
    ) -> ByteString {
        self.events += 1;
        let event_id = ByteString::from(
            format!(
                "layerwise-alarm-{}-{}",
                at.timestamp_nanos_opt().unwrap_or_default(),
                self.events
            )
            .into_bytes(),
        );
        let source = id(self.ns, ALARM);
        let mut event = AlarmConditionType::new_event(
            AlarmConditionType::event_type_id(),
            event_id.clone(),
            LocalizedText::new("en", message),
            &NamespaceMap::new(),
            time(at),
        );
        let base = &mut event.base.base.base;
        base.source_node = source.clone();
        base.source_name = "InspectionAlarm".into();
        base.severity = severity;
        let condition = &mut event.base.base;
        condition.condition_name = "InspectionAlarm".into();
        condition.retain = active && !acked;
        condition.enabled_state.id = true;
        condition.enabled_state.base.value = LocalizedText::new("en", "Enabled");
        event.base.acked_state.id = acked;
        event.base.acked_state.base.value = LocalizedText::new(
            "en",
            if acked {
                "Acknowledged"
            } else {
                "Unacknowledged"
            },
        );
        event.active_state.id = active;
        event.active_state.base.value =
            LocalizedText::new("en", if active { "Active" } else { "Inactive" });
        let server: NodeId = ObjectId::Server.into();
        let machine = id(self.ns, space::MACHINE);
        self.subscriptions.notify_events(
            [
                (&event as &dyn opcua::nodes::Event, &server),
                (&event as &dyn opcua::nodes::Event, &machine),
                (&event as &dyn opcua::nodes::Event, &source),
            ]
            .into_iter(),
        );
        event_id
    }
}

/// The values of each part (`Parts.Part<id>.<name>`), from its inspection metrics.
const PART_VALUES: [&str; 5] = ["AreaRatio", "IoU", "Unfused", "FusedFraction", "PostMean"];
