//! `alarm.jsonl`: the inspection alarm's history. The daemon appends `raised` (and, for an
//! alarm that is not latched, `cleared`) records; `layerwise alarm ack` appends `acknowledged`
//! records, which the running daemon picks up and switches the stack light off for.
//! `layerwise status` shows the state the history ends in.

use super::inspection::{FlagKind, Severity};
use super::lines::LinesLog;
use crate::logging::Escaped;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// One change of the alarm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum AlarmEvent {
    /// A flag at the alarm's severity switched it on.
    Raised {
        at: DateTime<Utc>,
        layer: u32,
        kind: FlagKind,
        severity: Severity,
        message: String,
    },
    /// An operator acknowledged it (`layerwise alarm ack`): the stack light goes off, the next
    /// flag raises it again.
    Acknowledged {
        at: DateTime<Utc>,
        by: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        note: Option<String>,
    },
    /// A clean layer switched an alarm that is not latched off.
    Cleared { at: DateTime<Utc>, layer: u32 },
}

/// Where the history leaves the alarm.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum AlarmState {
    /// Never raised, or cleared by a clean layer.
    Off,
    /// On since `layer`, waiting for an operator.
    Raised {
        layer: u32,
        kind: FlagKind,
        at: DateTime<Utc>,
        message: String,
    },
    /// The raise of `layer` was acknowledged.
    Acknowledged {
        layer: u32,
        by: String,
        at: DateTime<Utc>,
        note: Option<String>,
    },
}

impl AlarmState {
    /// The state after `events`, oldest first. An acknowledgement with no raise open changes
    /// nothing.
    pub fn replay(events: &[AlarmEvent]) -> AlarmState {
        let mut state = AlarmState::Off;
        for event in events {
            state = match (event, state) {
                (
                    AlarmEvent::Raised {
                        at,
                        layer,
                        kind,
                        message,
                        ..
                    },
                    _,
                ) => AlarmState::Raised {
                    layer: *layer,
                    kind: *kind,
                    at: *at,
                    message: message.clone(),
                },
                (AlarmEvent::Acknowledged { at, by, note }, AlarmState::Raised { layer, .. }) => {
                    AlarmState::Acknowledged {
                        layer,
                        by: by.clone(),
                        at: *at,
                        note: note.clone(),
                    }
                }
                (AlarmEvent::Cleared { .. }, _) => AlarmState::Off,
                (_, state) => state,
            };
        }
        state
    }

    pub fn is_raised(&self) -> bool {
        matches!(self, AlarmState::Raised { .. })
    }
}

impl fmt::Display for AlarmState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            AlarmState::Off => f.write_str("off"),
            AlarmState::Raised {
                layer,
                kind,
                at,
                message,
            } => write!(
                f,
                "RAISED since layer {layer} at {} ({kind}: {}); acknowledge with `layerwise alarm ack --build DIR`",
                at.format("%Y-%m-%d %H:%M:%S UTC"),
                Escaped(message)
            ),
            AlarmState::Acknowledged {
                layer,
                by,
                at,
                note,
            } => {
                // Who and the note come from a file anyone with the build's rights can write:
                // shown escaped, never acted on by the terminal.
                write!(
                    f,
                    "acknowledged by {} at {} (raised at layer {layer})",
                    Escaped(by),
                    at.format("%Y-%m-%d %H:%M:%S UTC")
                )?;
                match note {
                    Some(note) => write!(f, ": {}", Escaped(note)),
                    None => Ok(()),
                }
            }
        }
    }
}

/// The alarm history of a build, open for appending.
pub type AlarmLog = LinesLog<AlarmEvent>;

/// The alarm state of a build (`None` when it never had an alarm history).
pub fn state(dir: &Path) -> Option<AlarmState> {
    let events = AlarmLog::read(&dir.join(super::ALARM)).ok()?;
    (!events.is_empty()).then(|| AlarmState::replay(&events))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(s: i64) -> DateTime<Utc> {
        DateTime::from_timestamp(1_800_000_000 + s, 0).unwrap()
    }

    fn raised(layer: u32) -> AlarmEvent {
        AlarmEvent::Raised {
            at: at(i64::from(layer)),
            layer,
            kind: FlagKind::Spatter,
            severity: Severity::Critical,
            message: "spots".into(),
        }
    }

    #[test]
    fn the_history_replays_to_raised_acknowledged_and_raised_again() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::ALARM);
        assert_eq!(state(dir.path()), None);
        let (mut log, old) = AlarmLog::open(&path, false).unwrap();
        assert!(old.is_empty());
        let ack = AlarmEvent::Acknowledged {
            at: at(100),
            by: "ana".into(),
            note: Some("checked the plate".into()),
        };
        // An acknowledgement with nothing raised changes nothing.
        AlarmLog::append_only(&path).unwrap().append(&ack).unwrap();
        assert_eq!(state(dir.path()), Some(AlarmState::Off));
        log.append(&raised(6)).unwrap();
        let now = state(dir.path()).unwrap();
        assert!(now.is_raised());
        assert!(now.to_string().starts_with("RAISED since layer 6"), "{now}");
        AlarmLog::append_only(&path).unwrap().append(&ack).unwrap();
        let now = state(dir.path()).unwrap();
        assert_eq!(
            now.to_string(),
            "acknowledged by ana at 2027-01-15 08:01:40 UTC (raised at layer 6): checked the plate"
        );
        log.append(&raised(9)).unwrap();
        let events = AlarmLog::read(&path).unwrap();
        assert_eq!(events.len(), 4);
        assert!(matches!(
            AlarmState::replay(&events),
            AlarmState::Raised { layer: 9, .. }
        ));
        let mut cleared = events.clone();
        cleared.push(AlarmEvent::Cleared {
            at: at(200),
            layer: 10,
        });
        assert_eq!(AlarmState::replay(&cleared), AlarmState::Off);
    }
}
