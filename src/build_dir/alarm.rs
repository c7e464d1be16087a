//! `alarm.jsonl`: the inspection alarm's history. The daemon appends `raised` (and, for an
//! alarm that is not latched, `cleared`) records; `layerwise alarm ack` appends `acknowledged`
//! records, which the running daemon picks up and switches the stack light off for.
//! `layerwise status` shows the state the history ends in.

use super::inspection::{FlagKind, Severity};
use super::lines::{JournalError, LinesLog};
use crate::logging::Escaped;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};

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
    /// alarm.jsonl cannot be read (a damaged line): the alarm may be raised, and is shown as if
    /// it were.
    Unreadable { reason: String },
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

    /// Whether an operator must look: raised, or its history cannot be read.
    pub fn needs_attention(&self) -> bool {
        matches!(
            self,
            AlarmState::Raised { .. } | AlarmState::Unreadable { .. }
        )
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
                "RAISED since layer {layer} at {} ({kind}: {}); acknowledge with `layerwise alarm ack --build DIR` or on the page",
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
            AlarmState::Unreadable { reason } => write!(
                f,
                "UNKNOWN, treat it as RAISED: {}; look at the newest flags (`layerwise status`, \
                 the page), then keep a copy of {} and repair or remove the damaged line",
                Escaped(reason),
                super::ALARM
            ),
        }
    }
}

/// The alarm history of a build, open for appending.
pub type AlarmLog = LinesLog<AlarmEvent>;

/// The alarm state of a build (`None` when it never had an alarm history); a history that
/// cannot be read is [`AlarmState::Unreadable`], never "no alarm".
pub fn state(dir: &Path) -> Option<AlarmState> {
    match history(dir) {
        Ok(events) => (!events.is_empty()).then(|| AlarmState::replay(&events)),
        Err(e) => Some(AlarmState::Unreadable {
            reason: unreadable_reason(&e),
        }),
    }
}

/// The alarm history of a build, oldest first (empty when it never had one).
pub fn history(dir: &Path) -> Result<Vec<AlarmEvent>, JournalError> {
    AlarmLog::read(&dir.join(super::ALARM))
}

/// Why the history cannot be read, in a few words (the journal's repair advice does not fit).
fn unreadable_reason(error: &JournalError) -> String {
    match error {
        JournalError::Corrupt {
            path, line, source, ..
        } => format!("{} line {line} is damaged ({source})", path.display()),
        other => crate::logging::chain(other),
    }
}

/// Longest name of who acknowledges, and note, in characters.
pub const MAX_BY_CHARS: usize = 64;
pub const MAX_NOTE_CHARS: usize = 1000;

/// Why an acknowledgement was not recorded.
#[derive(Debug, thiserror::Error)]
pub enum AckError {
    #[error(transparent)]
    NotABuild(#[from] super::NotABuild),
    #[error("{}: the alarm is not raised (it is {state}); nothing to acknowledge", dir.display())]
    NotRaised { dir: PathBuf, state: AlarmState },
    #[error(
        "the alarm was raised again (layer {raised}, at {raised_at}) after the raise of layer \
         {seen} the acknowledgement was for: look at layer {raised}, then acknowledge it"
    )]
    Another {
        raised: u32,
        raised_at: DateTime<Utc>,
        seen: u32,
    },
    #[error("{field} {problem}")]
    Invalid {
        field: &'static str,
        problem: &'static str,
    },
    #[error("cannot record the acknowledgement")]
    Log(#[source] JournalError),
    #[error("cannot record the acknowledgement")]
    Locked(#[source] super::lines::AppendIfError),
}

/// Records that `by` acknowledged the raised alarm of the build `dir` at `at` (with what was
/// checked or decided, `note`): the running daemon switches the stack light off; the next flag
/// at the alarm's severity raises it again. Refused when `dir` is not a build, when the alarm is
/// not raised (or its history cannot be read), and for a name or note with control characters
/// or beyond [`MAX_BY_CHARS`] / [`MAX_NOTE_CHARS`], and when `seen` (the raise the operator saw,
/// as the page sends it) is not the raise now. The check and the append are one step for the
/// log's other writers ([`AlarmLog::append_if`]). Returns the state after it.
pub fn acknowledge(
    dir: &Path,
    by: &str,
    note: Option<&str>,
    at: DateTime<Utc>,
    seen: Option<SeenRaise>,
) -> Result<AlarmState, AckError> {
    super::require_build(dir)?;
    let by = by.trim();
    let note = note.map(str::trim).filter(|n| !n.is_empty());
    let invalid = |field, problem| Err(AckError::Invalid { field, problem });
    if by.is_empty() {
        return invalid("by", "is empty: say who acknowledges");
    }
    if by.chars().count() > MAX_BY_CHARS {
        return invalid("by", "is longer than 64 characters");
    }
    if note.is_some_and(|n| n.chars().count() > MAX_NOTE_CHARS) {
        return invalid("note", "is longer than 1000 characters");
    }
    if by
        .chars()
        .chain(note.unwrap_or_default().chars())
        .any(crate::logging::is_hidden_char)
    {
        return invalid(
            "by or note",
            "holds control characters or bidirectional marks (one line of plain text)",
        );
    }
    let path = dir.join(super::ALARM);
    let ack = AlarmEvent::Acknowledged {
        at,
        by: by.to_string(),
        note: note.map(str::to_string),
    };
    // The raise is checked and the acknowledgement appended under the log's lock: a raise the
    // daemon appends meanwhile waits, and is never taken as acknowledged unseen.
    let check = |events: &[AlarmEvent]| {
        let state = AlarmState::replay(events);
        match (&state, seen) {
            (AlarmState::Raised { layer, at, .. }, Some(seen))
                if *layer != seen.layer || seen.at.is_some_and(|s| s != *at) =>
            {
                Err(AckError::Another {
                    raised: *layer,
                    raised_at: *at,
                    seen: seen.layer,
                })
            }
            _ if !state.is_raised() => Err(AckError::NotRaised {
                dir: dir.to_path_buf(),
                state,
            }),
            _ => Ok(()),
        }
    };
    // What refuses it is said without opening the log for writing (no empty log is made, and
    // a reader without write rights hears why); the check is made again under the lock.
    check(&AlarmLog::read(&path).map_err(AckError::Log)?)?;
    let mut events = AlarmLog::append_only(&path)
        .map_err(AckError::Log)?
        .append_if(&ack, check)
        .map_err(|e| match e {
            super::lines::AppendIfError::Log(e) => AckError::Log(e),
            busy => AckError::Locked(busy),
        })??;
    events.push(ack);
    Ok(AlarmState::replay(&events))
}

/// The raise an acknowledgement answers, as the page showed it: its layer, and when it was
/// raised (a raise of the same layer again is another).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SeenRaise {
    pub layer: u32,
    pub at: Option<DateTime<Utc>>,
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

    #[test]
    fn acknowledge_checks_the_build_the_state_and_the_text_and_a_damaged_log_is_unknown() {
        let dir = tempfile::tempdir().unwrap();
        let err = acknowledge(dir.path(), "ana", None, at(1), None).unwrap_err();
        assert!(matches!(err, AckError::NotABuild(_)), "{err}");
        std::fs::write(dir.path().join(crate::build_dir::JOURNAL), "").unwrap();
        let err = acknowledge(dir.path(), "ana", None, at(1), None).unwrap_err();
        assert!(err.to_string().contains("not raised (it is off)"), "{err}");
        let path = dir.path().join(crate::build_dir::ALARM);
        AlarmLog::append_only(&path)
            .unwrap()
            .append(&raised(4))
            .unwrap();
        for (by, note) in [("", None), ("a\u{1b}[2J", None), ("ana", Some("x\u{7}"))] {
            let err = acknowledge(dir.path(), by, note, at(2), None).unwrap_err();
            assert!(matches!(err, AckError::Invalid { .. }), "{err}");
        }
        // A page that showed the raise of layer 2 does not acknowledge layer 4's, nor one that
        // showed an earlier raise of layer 4.
        let seen = |layer, at| Some(SeenRaise { layer, at });
        let err = acknowledge(dir.path(), "ana", None, at(2), seen(2, None)).unwrap_err();
        assert!(
            matches!(
                err,
                AckError::Another {
                    raised: 4,
                    seen: 2,
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("look at layer 4"), "{err}");
        let err = acknowledge(dir.path(), "ana", None, at(2), seen(4, Some(at(3)))).unwrap_err();
        assert!(
            matches!(
                err,
                AckError::Another {
                    raised: 4,
                    seen: 4,
                    ..
                }
            ),
            "{err}"
        );
        let now = acknowledge(
            dir.path(),
            " ana ",
            Some("  checked  "),
            at(3),
            seen(4, Some(at(4))),
        )
        .unwrap();
        assert_eq!(
            now,
            AlarmState::Acknowledged {
                layer: 4,
                by: "ana".into(),
                at: at(3),
                note: Some("checked".into())
            }
        );
        // Damage before the last line: the state is unknown, shown as raised.
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::write(&path, format!("{{oops\n{text}")).unwrap();
        let state = state(dir.path()).unwrap();
        assert!(state.needs_attention() && !state.is_raised(), "{state}");
        assert!(
            state
                .to_string()
                .starts_with("UNKNOWN, treat it as RAISED: ")
                && state.to_string().contains("line 1 is damaged"),
            "{state}"
        );
        // Text from the log is printed with its control characters escaped.
        let shown = AlarmState::Acknowledged {
            layer: 1,
            by: "x\u{1b}]0;t\u{7}".into(),
            at: at(0),
            note: None,
        }
        .to_string();
        assert!(shown.contains("x\\u{1b}]0;t\\u{7}"), "{shown}");
    }
}
