//! One cause, one flag: what one cause explains on a layer is folded into one flag with its
//! evidence (a part's drifts beside its fusion or elevation flag, several drifts of one part, the
//! coverage regions inside a short-fed band), and a flag that continues one of the layer before
//! (same kind, view and part, overlapping place) is the same flag persisting: it carries the layer
//! it was first seen on (`since`) and raises no new alarm.

use crate::build_dir::inspection::{Flag, FlagKind};

/// How far apart (mm) two flags' boxes may be and still be the same place on consecutive layers.
const SAME_PLACE_MM: f64 = 2.0;

fn overlaps(a: &[f64; 4], b: &[f64; 4], slack: f64) -> bool {
    a[0] <= b[2] + slack && b[0] <= a[2] + slack && a[1] <= b[3] + slack && b[1] <= a[3] + slack
}

/// Whether at least half of box `a` lies in box `b`.
fn mostly_inside(a: &[f64; 4], b: &[f64; 4]) -> bool {
    let w = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let h = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    2.0 * w * h >= (a[2] - a[0]) * (a[3] - a[1])
}

fn evidence_of(f: &Flag) -> String {
    format!(
        "{}: {} (score {:.2}, threshold {:.2})",
        f.kind, f.message, f.score, f.threshold
    )
}

/// Folds what one cause explains into one flag (see the module doc); keeps the order of the
/// flags that stay.
pub fn group(flags: Vec<Flag>) -> Vec<Flag> {
    let mut keep: Vec<Flag> = Vec::with_capacity(flags.len());
    let mut folded: Vec<(usize, Flag)> = Vec::new();
    // The flag a drift of `part` folds into: a fusion or elevation flag of the part, else the
    // part's strongest drift.
    let strongest_drift = |part: i64| {
        flags
            .iter()
            .enumerate()
            .filter(|(_, f)| f.kind == FlagKind::Drift && f.part == Some(part))
            .max_by(|a, b| {
                (a.1.score / a.1.threshold)
                    .total_cmp(&(b.1.score / b.1.threshold))
                    .then(b.0.cmp(&a.0))
            })
            .map(|(i, _)| i)
    };
    let host = |i: usize, f: &Flag| -> Option<usize> {
        match f.kind {
            FlagKind::Drift => {
                let part = f.part?;
                flags
                    .iter()
                    .position(|g| {
                        g.part == Some(part)
                            && matches!(
                                g.kind,
                                FlagKind::UnderFusion | FlagKind::OverFusion | FlagKind::Elevation
                            )
                    })
                    .or_else(|| strongest_drift(part).filter(|&s| s != i))
            }
            FlagKind::Coverage => flags.iter().position(|g| {
                g.kind == FlagKind::ShortFeed && overlaps(&g.bbox_mm, &f.bbox_mm, 0.0)
            }),
            // A line inside an uneven region is its edge, not a scratch of its own.
            FlagKind::Streak => flags.iter().position(|g| {
                g.kind == FlagKind::Coverage && mostly_inside(&f.bbox_mm, &g.bbox_mm)
            }),
            _ => None,
        }
    };
    let mut index_of_kept = vec![usize::MAX; flags.len()];
    let hosts: Vec<Option<usize>> = flags.iter().enumerate().map(|(i, f)| host(i, f)).collect();
    for (i, f) in flags.iter().enumerate() {
        match hosts[i] {
            Some(h) if hosts[h].is_none() => folded.push((h, f.clone())),
            _ => {
                index_of_kept[i] = keep.len();
                keep.push(f.clone());
            }
        }
    }
    for (h, f) in folded {
        let target = &mut keep[index_of_kept[h]];
        target.evidence.push(evidence_of(&f));
        if f.severity > target.severity {
            target.severity = f.severity;
        }
    }
    keep
}

/// Marks the flags of this layer that continue one of `before` (the flags of the layer inspected
/// just before, `before_layer`).
pub fn mark_persisting(flags: &mut [Flag], before: &[Flag], before_layer: u32) {
    for f in flags.iter_mut() {
        let earlier = before.iter().find(|g| {
            g.kind == f.kind
                && g.view == f.view
                && g.part == f.part
                && overlaps(&g.bbox_mm, &f.bbox_mm, SAME_PLACE_MM)
        });
        if let Some(g) = earlier {
            f.since = Some(g.since.unwrap_or(before_layer));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::inspection::Severity;

    fn flag(kind: FlagKind, part: Option<i64>, score: f64, bbox_mm: [f64; 4]) -> Flag {
        Flag {
            kind,
            class: None,
            severity: Severity::Warning,
            part,
            view: "post_top".into(),
            bbox_mm,
            bbox_px: [0; 4],
            score,
            threshold: 1.0,
            message: format!("{kind}"),
            since: None,
            evidence: vec![],
        }
    }

    #[test]
    fn a_part_s_drifts_fold_into_its_fusion_flag_and_persisting_flags_keep_their_first_layer() {
        let b = [40.0, 44.0, 60.0, 56.0];
        let mut under = flag(FlagKind::UnderFusion, Some(3), 1.0, b);
        under.severity = Severity::Critical;
        let flags = vec![
            flag(FlagKind::Drift, Some(3), 12.0, b),
            under,
            flag(FlagKind::Drift, Some(3), 20.0, b),
            flag(FlagKind::Drift, Some(1), 11.0, b),
            flag(FlagKind::Drift, Some(1), 15.0, b),
            flag(FlagKind::Streak, None, 9.0, [-40.0, 12.0, 95.0, 13.0]),
        ];
        let grouped = group(flags);
        let kinds: Vec<_> = grouped.iter().map(|f| (f.kind, f.part)).collect();
        assert_eq!(
            kinds,
            vec![
                (FlagKind::UnderFusion, Some(3)),
                (FlagKind::Drift, Some(1)),
                (FlagKind::Streak, None)
            ]
        );
        assert_eq!(grouped[0].evidence.len(), 2);
        assert_eq!(grouped[1].score, 15.0);
        assert_eq!(grouped[1].evidence.len(), 1);

        let mut next = vec![
            flag(FlagKind::Streak, None, 9.0, [-40.0, 12.5, 95.0, 13.5]),
            flag(FlagKind::Streak, None, 9.0, [-40.0, 60.0, 95.0, 61.0]),
        ];
        mark_persisting(&mut next, &grouped, 7);
        assert_eq!(next[0].since, Some(7));
        assert_eq!(next[1].since, None);
        let mut third = vec![flag(FlagKind::Streak, None, 9.0, [-40.0, 12.0, 95.0, 13.0])];
        mark_persisting(&mut third, &next, 8);
        assert_eq!(third[0].since, Some(7));
    }
}
