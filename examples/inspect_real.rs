//! The inspection on real powder-bed frames (`shared/data/real/pblm`, see its README): each
//! class's frames following the good frames as consecutive layers of one build, inspected with
//! the default configuration as `layerwise inspect --frames DIR` does (no calibration: the frames
//! taken as top-down; no vectors; no recoater axis or plate crop set), and the 3772 x 3302
//! `Plateform_Powder_Uneven` frames as a sequence of their own. Prints the table of
//! docs/inspection.md: per class, layers flagged (any severity, critical) and by kind.
//!
//! Then the same sequences with the good frames and each class in reverse name order: each layer
//! follows other layers than the ones it was developed against, and with the good layers, the
//! largest score / threshold any check reached on them (how near a false alarm they came).
//!
//! `cargo run --release --example inspect_real [-- DATA_DIR [--json OUT_DIR]]`

use layerwise::build_dir::inspection::{FlagKind, InspectionRecord, Severity};
use layerwise::config::inspection::InspectionConfig;
use layerwise::inspect::{offline, Inspector};
use layerwise::rectify::Rectifier;
use layerwise::shot::{Light, Phase, View};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

const GOOD: &str = "No_Defect";
const CLASSES: [&str; 3] = [
    "Powder_Uneven",
    "Powder_Uneven_With_Scratch",
    "Deformation_With_Scratch",
];
const PLATFORM: &str = "Plateform_Powder_Uneven";

fn pictures(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
        .collect();
    v.sort();
    v
}

/// Inspects `paths` as layers 1.. of pre_top with the default configuration.
fn inspect(paths: &[PathBuf]) -> Vec<InspectionRecord> {
    let view = View {
        phase: Phase::Pre,
        light: Light::Top,
    };
    let frames = offline::as_layers(paths, view);
    let (w, h) = offline::frame_size(&frames.paths).expect("first frame");
    let (calibration, grid) = offline::top_down(w, h, None).expect("top-down");
    let rectifier =
        Rectifier::new(&calibration.camera(), grid, Default::default(), 0).expect("rectifier");
    let mut inspector = Inspector::new(&InspectionConfig::default(), grid, &[view], None);
    let at = chrono::Utc::now();
    let (records, skipped) = offline::run(&mut inspector, &rectifier, &frames, 1, u32::MAX, at);
    assert!(skipped.is_empty(), "{} frames skipped", skipped.len());
    records
}

/// Layers flagged among `records`: any severity, critical, and per kind.
struct Count {
    layers: usize,
    any: usize,
    critical: usize,
    new: usize,
    kinds: BTreeMap<FlagKind, usize>,
}

fn count(records: &[&InspectionRecord]) -> Count {
    let mut c = Count {
        layers: records.len(),
        any: 0,
        critical: 0,
        new: 0,
        kinds: BTreeMap::new(),
    };
    for r in records {
        let flags: Vec<_> = r
            .flags
            .iter()
            .filter(|f| f.severity >= Severity::Warning)
            .collect();
        c.any += usize::from(!flags.is_empty());
        c.critical += usize::from(flags.iter().any(|f| f.severity == Severity::Critical));
        c.new += flags.iter().filter(|f| f.since.is_none()).count();
        let kinds: BTreeSet<FlagKind> = flags.iter().map(|f| f.kind).collect();
        for k in kinds {
            *c.kinds.entry(k).or_default() += 1;
        }
    }
    c
}

fn pct(n: usize, of: usize) -> String {
    format!("{n}/{of} ({:.0}%)", 100.0 * n as f64 / of.max(1) as f64)
}

fn row(name: &str, c: &Count) -> String {
    let kinds: Vec<String> = c
        .kinds
        .iter()
        .map(|(k, n)| format!("{k} {}", pct(*n, c.layers)))
        .collect();
    format!(
        "| {name} | {} | {} | {} | {} |",
        c.layers,
        pct(c.any, c.layers),
        pct(c.critical, c.layers),
        if kinds.is_empty() {
            "-".to_string()
        } else {
            kinds.join(", ")
        }
    )
}

/// One table: the good frames (then each class) as sequences, in name order or reversed.
struct Table {
    rows: Vec<String>,
    notes: Vec<String>,
    ms: Vec<f64>,
}

/// The largest score / threshold of any flag kind on the good layers, and the flags there.
fn good_margin(records: &[&InspectionRecord]) -> String {
    let mut worst: BTreeMap<FlagKind, f64> = BTreeMap::new();
    for f in records.iter().flat_map(|r| &r.flags) {
        let ratio = f.score / f.threshold;
        let w = worst.entry(f.kind).or_insert(ratio);
        *w = w.max(ratio);
    }
    if worst.is_empty() {
        return "no flag at any severity".into();
    }
    worst
        .iter()
        .map(|(k, r)| format!("{k} score/threshold up to {r:.2}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn sequences(data: &Path, good: &[PathBuf], reversed: bool, json: Option<&Path>) -> Table {
    let mut good = good.to_vec();
    if reversed {
        good.reverse();
    }
    let mut table = Table {
        rows: Vec::new(),
        notes: Vec::new(),
        ms: Vec::new(),
    };
    for class in CLASSES {
        let mut frames = pictures(&data.join(class));
        if reversed {
            frames.reverse();
        }
        let sequence: Vec<PathBuf> = good.iter().chain(&frames).cloned().collect();
        let records = inspect(&sequence);
        if let Some(dir) = json {
            std::fs::create_dir_all(dir).expect("json dir");
            let text: String = records
                .iter()
                .map(|r| serde_json::to_string(r).expect("json") + "\n")
                .collect();
            let name = format!("{class}{}.jsonl", if reversed { "-reversed" } else { "" });
            std::fs::write(dir.join(name), text).expect("write");
        }
        table.ms.extend(records.iter().map(|r| r.ms));
        let (before, after): (Vec<&InspectionRecord>, Vec<&InspectionRecord>) =
            records.iter().partition(|r| r.layer as usize <= good.len());
        // The good layers open every sequence the same way (inspection looks only back): one
        // row, the first sequence's.
        if table.rows.is_empty() {
            table.rows.push(row(
                &format!("{GOOD} (layers 1..{})", good.len()),
                &count(&before),
            ));
            table
                .notes
                .push(format!("{GOOD}: {}", good_margin(&before)));
        }
        table.rows.push(row(
            &format!("{class} (layers {}..)", good.len() + 1),
            &count(&after),
        ));
        let axis = records.last().and_then(|r| r.axis.clone());
        let decided = records
            .iter()
            .find(|r| r.axis.as_ref().is_some_and(|a| a.source != "undetermined"))
            .map(|r| r.layer);
        table.notes.push(format!(
            "{class}: recoater axis {} ({}) from layer {}",
            axis.as_ref().map_or("-", |a| a.axis.as_str()),
            axis.as_ref().map_or("-", |a| a.source.as_str()),
            decided.map_or("-".into(), |l| l.to_string())
        ));
    }
    table
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let data = args
        .first()
        .filter(|a| !a.starts_with("--"))
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("../shared/data/real/pblm"));
    let json = args
        .iter()
        .position(|a| a == "--json")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from);
    let mut platform_detail = None;
    let good = pictures(&data.join(GOOD));
    let started = std::time::Instant::now();
    let mut ms = Vec::new();
    // The same frames as another sequence: every class and the good frames in reverse name
    // order, so each layer follows other layers than the ones it was looked at after.
    for (order, reversed) in [("name order", false), ("reversed name order", true)] {
        let table = sequences(&data, &good, reversed, json.as_deref());
        ms.extend(table.ms);
        println!("frames in {order}:");
        println!(
            "| frames (sequence: {} good layers, then the class) | layers | flagged (any) | critical | by kind (layers) |",
            good.len()
        );
        println!("| --- | --- | --- | --- | --- |");
        for r in &table.rows {
            println!("{r}");
        }
        if !reversed {
            let platform = pictures(&data.join(PLATFORM));
            let records = inspect(&platform);
            let all: Vec<&InspectionRecord> = records.iter().collect();
            println!(
                "{}",
                row(&format!("{PLATFORM} (a build of its own)"), &count(&all))
            );
            platform_detail = Some((platform, records));
        }
        println!();
        for a in &table.notes {
            println!("{order}: {a}");
        }
        println!();
    }
    let (platform, records) = platform_detail.expect("name order ran");
    for r in &records {
        let flags: Vec<String> = r
            .flags
            .iter()
            .map(|f| {
                format!(
                    "{} {}{}",
                    f.kind,
                    f.severity,
                    f.since.map_or(String::new(), |s| format!(" since {s}"))
                )
            })
            .collect();
        println!(
            "{PLATFORM} layer {} ({}): {}",
            r.layer,
            platform[r.layer as usize - 1]
                .file_name()
                .map_or(String::new(), |n| n.to_string_lossy().into_owned()),
            if flags.is_empty() {
                "no flag".into()
            } else {
                flags.join(", ")
            }
        );
        for n in &r.notes {
            println!("    {}: {}", n.level, n.message);
        }
    }
    ms.sort_by(|a, b| a.total_cmp(b));
    println!(
        "inspection per 1024 x 1024 layer (after decoding): median {:.1} ms; all in {:.1} s",
        ms.get(ms.len() / 2).copied().unwrap_or(0.0),
        started.elapsed().as_secs_f64()
    );
}
