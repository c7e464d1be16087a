//! Wakes the page server's watch of a build as soon as one of the files it reads changes
//! (inotify on Linux, through `notify`), so a layer's flags reach open pages when the daemon
//! writes them, not up to a look period later. The watch still looks every
//! [`WATCH_PERIOD`](super::WATCH_PERIOD) as well: where no change notification is to be had (a
//! network file system, the system's limit of watches reached), that look is what finds changes.

use crate::build_dir::{ALARM, INSPECTION, JOURNAL, STATUS};
use notify::event::ModifyKind;
use notify::{Event, EventKind, RecommendedWatcher, RecursiveMode, Watcher};
use std::path::Path;
use std::sync::Arc;
use tokio::sync::Notify;

/// The files of a build whose changes the page shows.
const WATCHED: [&str; 4] = [JOURNAL, INSPECTION, ALARM, STATUS];

/// Change notifications of one build directory; [`BuildWake::changed`] waits for the next.
pub(super) struct BuildWake {
    /// Kept for as long as notifications are wanted (dropping it ends them).
    _watcher: RecommendedWatcher,
    notify: Arc<Notify>,
}

impl BuildWake {
    /// Notifications of `dir`'s watched files, or why the system gives none (the directory is
    /// gone, or `fs.inotify.max_user_instances` / `max_user_watches` is reached).
    pub(super) fn new(dir: &Path) -> notify::Result<BuildWake> {
        let notify = Arc::new(Notify::new());
        let tell = notify.clone();
        let mut watcher = notify::recommended_watcher(move |event: notify::Result<Event>| {
            if event.is_ok_and(|e| wakes(&e)) {
                // Stored if the watch is busy: changes during a look wake it once more.
                tell.notify_one();
            }
        })?;
        watcher.watch(dir, RecursiveMode::NonRecursive)?;
        Ok(BuildWake {
            _watcher: watcher,
            notify,
        })
    }

    /// Returns after a watched file changed (at once if one changed since the last call).
    pub(super) async fn changed(&self) {
        self.notify.notified().await;
    }
}

/// Whether `event` is a change of a watched file's contents or name, or a lost queue (whatever
/// changed must be looked at). Opening and reading, the page's own, are not.
fn wakes(event: &Event) -> bool {
    if event.need_rescan() {
        return true;
    }
    let changed = matches!(
        event.kind,
        EventKind::Create(_)
            | EventKind::Remove(_)
            | EventKind::Modify(ModifyKind::Data(_) | ModifyKind::Name(_) | ModifyKind::Any)
    );
    changed
        && event.paths.iter().any(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| WATCHED.contains(&n))
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;
    use std::time::Duration;

    /// Whether `wake` is woken within `wait`.
    fn woken(rt: &tokio::runtime::Runtime, wake: &BuildWake, wait: Duration) -> bool {
        rt.block_on(async { tokio::time::timeout(wait, wake.changed()).await.is_ok() })
    }

    /// Woken within `wait`, then every late notification of the same change let go of, so
    /// that the next check sees only its own.
    fn woken_once(rt: &tokio::runtime::Runtime, wake: &BuildWake, wait: Duration) -> bool {
        let woken = woken(rt, wake, wait);
        std::thread::sleep(Duration::from_millis(100));
        let _ = self::woken(rt, wake, Duration::from_millis(1));
        woken
    }

    #[test]
    fn appends_and_replacements_of_the_build_files_wake_reads_and_other_files_do_not() {
        let dir = tempfile::tempdir().unwrap();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let inspection = dir.path().join(INSPECTION);
        std::fs::write(&inspection, "{}\n").unwrap();
        let wake = BuildWake::new(dir.path()).expect("inotify on the test machine");
        // Not woken by what the page itself does, nor by the slices and temporary files.
        let _ = std::fs::read(&inspection).unwrap();
        std::fs::create_dir(dir.path().join("series_front")).unwrap();
        std::fs::write(dir.path().join("series_front").join("L00001.dcm"), b"x").unwrap();
        std::fs::write(dir.path().join(".status.json.1.tmp"), b"{}").unwrap();
        assert!(!woken(&rt, &wake, Duration::from_millis(300)));
        // A line appended to the inspection log.
        let mut log = std::fs::OpenOptions::new()
            .append(true)
            .open(&inspection)
            .unwrap();
        log.write_all(b"{\"layer\":1}\n").unwrap();
        drop(log);
        assert!(woken_once(&rt, &wake, Duration::from_secs(20)));
        // status.json replaced atomically (a temporary file renamed over it).
        std::fs::rename(
            dir.path().join(".status.json.1.tmp"),
            dir.path().join(STATUS),
        )
        .unwrap();
        assert!(woken_once(&rt, &wake, Duration::from_secs(20)));
        // The journal created.
        std::fs::write(dir.path().join(JOURNAL), b"{}\n").unwrap();
        assert!(woken(&rt, &wake, Duration::from_secs(20)));
    }

    #[test]
    fn a_directory_that_cannot_be_watched_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        assert!(BuildWake::new(&dir.path().join("missing")).is_err());
    }
}
