//! Training data: a folder of class folders (as `../shared/data/real/pblm/`), a `flaws` output
//! folder (its COCO `labels.json`: flaw patches against flaw-free controls) or a build whose
//! operators left verdicts on flags ([`super::verdicts`]), and the split into training and
//! validation parts that keeps neighbours apart.
//!
//! The split never draws frames at random: neighbouring frames of one sequence are near-twins,
//! so a random split measures memory, not generalisation. Frames: a *sequence* is the frames of
//! one class whose names share the stem before their trailing number (`converted__0033` →
//! `converted__`, `PowderRecoat_20210909_143308` → `PowderRecoat_20210909_`), ordered by that
//! number; in a sequence of 4 frames or more the last `ceil(F x n)` are validation and the 2 before
//! them (1 in sequences under 20) are dropped as a guard band. Patches and verdicts: the last
//! `ceil(F x layers)` layers are validation, the layer before them is dropped, and a training
//! patch of a flaw that also has a validation patch is dropped.

use super::error::LearnError;
use super::input::Gray;
use serde::Deserialize;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

pub const LABELS: &str = "labels.json";
const IMAGE_EXT: [&str; 6] = ["jpg", "jpeg", "png", "tif", "tiff", "bmp"];
/// Classes taken as "no defect" when `--normal` does not say (case ignored).
const NORMAL_NAMES: [&str; 5] = ["no_defect", "normal", "control", "ok", "good"];

/// Where the training data came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataKind {
    ClassFolders,
    Flaws,
    Verdicts,
}

impl DataKind {
    pub fn name(self) -> &'static str {
        match self {
            DataKind::ClassFolders => "class-folders",
            DataKind::Flaws => "flaws",
            DataKind::Verdicts => "verdicts",
        }
    }
}

/// A window of a picture (verdicts: the flag's box grown to the model's input).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    pub x0: usize,
    pub y0: usize,
    pub w: usize,
    pub h: usize,
}

/// One labelled picture.
#[derive(Clone, Debug)]
pub struct Item {
    pub path: PathBuf,
    /// Path relative to the data root (the hash and the messages use it).
    pub rel: String,
    pub class: usize,
    /// Frames: the sequence stem; patches and verdicts: empty.
    pub seq: String,
    /// Frames: the number in the name; patches and verdicts: the layer.
    pub order: i64,
    /// Patches: the flaw it shows or is the control of.
    pub flaw: Option<u32>,
    /// Verdicts: the window of the rectified view.
    pub window: Option<Window>,
}

/// A labelled data set.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub kind: DataKind,
    pub root: PathBuf,
    pub classes: Vec<String>,
    pub normal: String,
    pub items: Vec<Item>,
    /// mm per pixel of the pictures, when known (patches, views).
    pub pixel_mm: Option<f64>,
}

/// Which part an item is in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    Train,
    Val,
    Dropped,
}

fn is_image(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXT.contains(&e.to_ascii_lowercase().as_str()))
}

/// Frames left out on either side of a held-out run of a sequence of `n`: near-twins of their
/// neighbours.
pub(crate) fn guard_frames(n: usize) -> usize {
    if n >= 20 {
        2
    } else {
        1
    }
}

/// `converted__0033` → (`converted__`, 33).
pub fn sequence_key(stem: &str) -> (String, i64) {
    let digits = stem.len() - stem.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    let (head, tail) = stem.split_at(stem.len() - digits);
    (head.to_string(), tail.parse().unwrap_or(0))
}

fn read_dir_sorted(dir: &Path) -> Result<Vec<PathBuf>, LearnError> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|source| LearnError::Read {
            path: dir.to_path_buf(),
            source,
        })?
        .flatten()
        .map(|e| e.path())
        .collect();
    out.sort();
    Ok(out)
}

/// The normal class: `normal` when given (it must be a class), else a class named like
/// No_Defect, normal, control, ok or good.
pub fn pick_normal(
    root: &Path,
    classes: &[String],
    normal: Option<&str>,
) -> Result<String, LearnError> {
    if let Some(n) = normal {
        return classes.iter().find(|c| *c == n).cloned().ok_or_else(|| {
            LearnError::data(
                root,
                format!("--normal {n} is not one of the classes {classes:?}"),
            )
        });
    }
    classes
        .iter()
        .find(|c| NORMAL_NAMES.contains(&c.to_ascii_lowercase().as_str()))
        .cloned()
        .ok_or_else(|| {
            LearnError::data(
                root,
                format!("which of the classes {classes:?} is the defect-free one? Say it with --normal CLASS"),
            )
        })
}

/// A folder with one subfolder of pictures per class.
pub fn open_class_folders(root: &Path, normal: Option<&str>) -> Result<Dataset, LearnError> {
    let mut classes = Vec::new();
    let mut items = Vec::new();
    for dir in read_dir_sorted(root)?.into_iter().filter(|p| p.is_dir()) {
        let name = dir
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_string();
        let pictures: Vec<PathBuf> = read_dir_sorted(&dir)?
            .into_iter()
            .filter(|p| p.is_file() && is_image(p))
            .collect();
        if pictures.is_empty() {
            continue;
        }
        let class = classes.len();
        classes.push(name.clone());
        for path in pictures {
            let stem = path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default();
            let (seq, order) = sequence_key(stem);
            let file = path
                .file_name()
                .and_then(|s| s.to_str())
                .unwrap_or_default();
            items.push(Item {
                rel: format!("{name}/{file}"),
                path,
                class,
                seq,
                order,
                flaw: None,
                window: None,
            });
        }
    }
    if classes.len() < 2 {
        return Err(LearnError::data(
            root,
            format!(
                "{} class folder(s) with pictures; training needs a folder per class (2 or more), each holding .jpg/.png/.tif pictures, or a flaws output (labels.json) or a build with verdicts.jsonl",
                classes.len()
            ),
        ));
    }
    let normal = pick_normal(root, &classes, normal)?;
    Ok(Dataset {
        kind: DataKind::ClassFolders,
        root: root.to_path_buf(),
        classes,
        normal,
        items,
        pixel_mm: None,
    })
}

#[derive(Deserialize)]
struct Coco {
    images: Vec<CocoImage>,
}

#[derive(Deserialize)]
struct CocoImage {
    file_name: String,
    layer: u32,
    kind: String,
    flaw_id: u32,
    grid: crate::geometry::Grid,
}

/// A `layerwise flaws --build` output: classes `control` (normal) and `flaw`.
pub fn open_flaws(root: &Path) -> Result<Dataset, LearnError> {
    let path = root.join(LABELS);
    let text = std::fs::read_to_string(&path).map_err(|source| LearnError::Read {
        path: path.clone(),
        source,
    })?;
    let coco: Coco = serde_json::from_str(&text).map_err(|source| LearnError::Parse {
        path: path.clone(),
        source,
    })?;
    let classes = vec!["control".to_string(), "flaw".to_string()];
    let mut items = Vec::new();
    let mut pixel_mm = None;
    for img in coco.images {
        let class = match img.kind.as_str() {
            "control" => 0,
            "flaw" => 1,
            other => {
                return Err(LearnError::data(
                    &path,
                    format!(
                        "{}: kind {other:?} is neither flaw nor control",
                        img.file_name
                    ),
                ))
            }
        };
        pixel_mm.get_or_insert(img.grid.pixel_mm);
        items.push(Item {
            path: root.join(&img.file_name),
            rel: img.file_name,
            class,
            seq: String::new(),
            order: i64::from(img.layer),
            flaw: Some(img.flaw_id),
            window: None,
        });
    }
    for (c, name) in classes.iter().enumerate() {
        if !items.iter().any(|i| i.class == c) {
            return Err(LearnError::data(
                &path,
                format!("no {name} patches: training needs flaws and controls"),
            ));
        }
    }
    Ok(Dataset {
        kind: DataKind::Flaws,
        root: root.to_path_buf(),
        classes,
        normal: "control".into(),
        items,
        pixel_mm,
    })
}

impl Dataset {
    /// Items per class name.
    pub fn counts(&self, parts: Option<(&[Part], Part)>) -> BTreeMap<String, usize> {
        let mut out: BTreeMap<String, usize> =
            self.classes.iter().map(|c| (c.clone(), 0)).collect();
        for (i, item) in self.items.iter().enumerate() {
            if parts.is_none_or(|(p, want)| p[i] == want) {
                *out.entry(self.classes[item.class].clone()).or_default() += 1;
            }
        }
        out
    }

    /// The split rule's name.
    pub fn rule(&self) -> &'static str {
        match self.kind {
            DataKind::ClassFolders => "sequence-tail",
            _ => "layer-tail",
        }
    }

    /// The deterministic split (independent of the seed).
    pub fn split(&self, val_fraction: f64) -> Vec<Part> {
        let f = val_fraction.clamp(0.0, 0.9);
        let mut parts = vec![Part::Train; self.items.len()];
        if f == 0.0 {
            return parts;
        }
        match self.kind {
            DataKind::ClassFolders => {
                for idx in self.sequences() {
                    let n = idx.len();
                    if n < 4 {
                        continue;
                    }
                    let val = ((f * n as f64).ceil() as usize).clamp(1, n - 2);
                    let guard = guard_frames(n);
                    for (k, &i) in idx.iter().enumerate() {
                        if k >= n - val {
                            parts[i] = Part::Val;
                        } else if k + guard >= n - val {
                            parts[i] = Part::Dropped;
                        }
                    }
                }
            }
            DataKind::Flaws | DataKind::Verdicts => {
                let layers = self.layers();
                let n = layers.len();
                if n < 3 {
                    return parts;
                }
                let val = ((f * n as f64).ceil() as usize).clamp(1, n - 2);
                let cut = layers[n - val];
                let guard = layers[n - val - 1];
                for (i, it) in self.items.iter().enumerate() {
                    if it.order >= cut {
                        parts[i] = Part::Val;
                    } else if it.order == guard {
                        parts[i] = Part::Dropped;
                    }
                }
                self.leave_out_held_flaws(&mut parts);
            }
        }
        parts
    }

    /// The item indices of every sequence (one class's frames sharing a stem), in frame order.
    pub(crate) fn sequences(&self) -> Vec<Vec<usize>> {
        let mut seqs: BTreeMap<(usize, &str), Vec<usize>> = BTreeMap::new();
        for (i, it) in self.items.iter().enumerate() {
            seqs.entry((it.class, &it.seq)).or_default().push(i);
        }
        let mut seqs: Vec<Vec<usize>> = seqs.into_values().collect();
        for idx in &mut seqs {
            idx.sort_by_key(|&i| (self.items[i].order, self.items[i].rel.clone()));
        }
        seqs
    }

    /// The layers of the patches or verdicts, ascending.
    pub(crate) fn layers(&self) -> Vec<i64> {
        let layers: BTreeSet<i64> = self.items.iter().map(|i| i.order).collect();
        layers.into_iter().collect()
    }

    /// No flaw on both sides: the training patches of a flaw that has held-out patches are
    /// left out.
    pub(crate) fn leave_out_held_flaws(&self, parts: &mut [Part]) {
        let seen: BTreeSet<u32> = self
            .items
            .iter()
            .zip(parts.iter())
            .filter(|(_, p)| **p == Part::Val)
            .filter_map(|(i, _)| i.flaw)
            .collect();
        for (it, part) in self.items.iter().zip(parts.iter_mut()) {
            if *part == Part::Train && it.flaw.is_some_and(|f| seen.contains(&f)) {
                *part = Part::Dropped;
            }
        }
    }

    /// SHA-256 over the sorted lines `relative-path TAB sha256(file)` (verdict windows add
    /// their box), so the same files give the same hash however they were listed.
    pub fn hash(&self) -> Result<String, LearnError> {
        use rayon::prelude::*;
        let mut lines: Vec<String> = self
            .items
            .par_iter()
            .map(|it| {
                let bytes = std::fs::read(&it.path).map_err(|source| LearnError::Read {
                    path: it.path.clone(),
                    source,
                })?;
                let window = it
                    .window
                    .map(|w| format!("@{},{},{},{}", w.x0, w.y0, w.w, w.h))
                    .unwrap_or_default();
                Ok(format!(
                    "{}/{}{window}\t{}",
                    self.classes[it.class],
                    it.rel,
                    super::file::sha256_hex(&bytes)
                ))
            })
            .collect::<Result<_, LearnError>>()?;
        lines.sort();
        Ok(super::file::sha256_hex(lines.join("\n").as_bytes()))
    }
}

/// Decodes a picture (JPEG, PNG, TIFF, 8 or 16 bits) to grey on the 8-bit scale.
pub fn read_picture(path: &Path) -> Result<Gray, LearnError> {
    let bytes = crate::fsutil::read_regular(path).map_err(|source| LearnError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    if bytes.get(128..132) == Some(b"DICM".as_slice()) {
        return read_slice(path);
    }
    let decode = |source| LearnError::Decode {
        path: path.to_path_buf(),
        source,
    };
    if bytes.starts_with(&[0x89, b'P', b'N', b'G'])
        || bytes.starts_with(b"II")
        || bytes.starts_with(b"MM")
    {
        // 16-bit patches keep their precision.
        let img = image::load_from_memory(&bytes)
            .map_err(|e| decode(crate::rectify::RectifyError::Image(Box::new(e))))?;
        let g = img.to_luma16();
        let px = g.as_raw().iter().map(|&v| f32::from(v) / 257.0).collect();
        return Ok(Gray::new(g.width() as usize, g.height() as usize, px));
    }
    let luma = crate::rectify::decode_frame_luma(&bytes).map_err(decode)?;
    Ok(Gray::from_luma(&luma))
}

/// The picture of an item (a verdict's window cut from its view).
pub fn read_item(item: &Item) -> Result<Gray, LearnError> {
    let img = read_picture(&item.path)?;
    Ok(match item.window {
        Some(w) => cut(&img, w),
        None => img,
    })
}

/// A rectified view stored as a DICOM slice, on the 8-bit scale (16-bit linear views / 257).
pub fn read_slice(path: &Path) -> Result<Gray, LearnError> {
    use dicom_pixeldata::PixelDecoder;
    let bad = |detail: String| LearnError::data(path, detail);
    let dicom = |what, source: Box<dyn std::error::Error + Send + Sync>| LearnError::Dicom {
        path: path.to_path_buf(),
        what,
        source,
    };
    // Every stated length must fit in the file before dicom-rs sizes a read by it.
    match crate::dicom::check_lengths(path) {
        Err(crate::dicom::DicomError::Damaged { message, .. }) => return Err(bad(message)),
        Err(e) => return Err(dicom("check the lengths of", Box::new(e))),
        Ok(_) => {}
    }
    let obj =
        dicom_object::open_file(path).map_err(|e| dicom("read the DICOM file", Box::new(e)))?;
    let width = obj
        .element(dicom_dictionary_std::tags::WINDOW_WIDTH)
        .ok()
        .and_then(|e| e.to_float64().ok())
        .unwrap_or(256.0);
    let px = obj
        .decode_pixel_data()
        .map_err(|e| dicom("decode the pixel data of", Box::new(e)))?;
    let (w, h) = (px.columns() as usize, px.rows() as usize);
    let bytes = px.data();
    if px.bits_allocated() != 16 || bytes.len() < 2 * w * h {
        return Err(bad(format!(
            "{w}x{h} slice of {} bits is not a layerwise view",
            px.bits_allocated()
        )));
    }
    let scale = if width > 1000.0 { 1.0 / 257.0 } else { 1.0 };
    let values = bytes[..2 * w * h]
        .chunks_exact(2)
        .map(|b| f32::from(u16::from_le_bytes([b[0], b[1]])) * scale)
        .collect();
    Ok(Gray::new(w, h, values))
}

/// A window of `img`, clamped inside it.
pub fn cut(img: &Gray, w: Window) -> Gray {
    let (ww, wh) = (w.w.min(img.width), w.h.min(img.height));
    let x0 = w.x0.min(img.width - ww);
    let y0 = w.y0.min(img.height - wh);
    let mut px = Vec::with_capacity(ww * wh);
    for y in y0..y0 + wh {
        px.extend_from_slice(&img.px[y * img.width + x0..y * img.width + x0 + ww]);
    }
    Gray::new(ww, wh, px)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(class: usize, seq: &str, n: usize) -> Vec<Item> {
        (0..n)
            .map(|k| Item {
                path: PathBuf::new(),
                rel: format!("{seq}{k:04}"),
                class,
                seq: seq.into(),
                order: k as i64,
                flaw: None,
                window: None,
            })
            .collect()
    }

    #[test]
    fn sequences_split_at_their_tail_with_a_guard_band() {
        assert_eq!(sequence_key("converted__0033"), ("converted__".into(), 33));
        assert_eq!(
            sequence_key("PowderRecoat_20210909_143308"),
            ("PowderRecoat_20210909_".into(), 143308)
        );
        let mut items = frames(0, "a_", 100);
        items.extend(frames(1, "b_", 12));
        items.extend(frames(1, "c_", 3));
        let d = Dataset {
            kind: DataKind::ClassFolders,
            root: PathBuf::new(),
            classes: vec!["x".into(), "y".into()],
            normal: "y".into(),
            items,
            pixel_mm: None,
        };
        let parts = d.split(0.2);
        let count = |r: std::ops::Range<usize>, p: Part| r.filter(|&i| parts[i] == p).count();
        assert_eq!(count(0..100, Part::Val), 20);
        assert_eq!(count(0..100, Part::Dropped), 2);
        assert!(parts[77] == Part::Train && parts[78] == Part::Dropped && parts[80] == Part::Val);
        assert_eq!(
            (count(100..112, Part::Val), count(100..112, Part::Dropped)),
            (3, 1)
        );
        assert_eq!(count(112..115, Part::Train), 3);
    }

    #[test]
    fn patch_layers_split_and_a_flaw_never_sits_on_both_sides() {
        let items: Vec<Item> = (0..10)
            .map(|l| Item {
                path: PathBuf::new(),
                rel: format!("p{l}"),
                class: l % 2,
                seq: String::new(),
                order: l as i64,
                flaw: Some(if l == 2 { 9 } else { l as u32 }),
                window: None,
            })
            .chain(std::iter::once(Item {
                path: PathBuf::new(),
                rel: "q".into(),
                class: 1,
                seq: String::new(),
                order: 9,
                flaw: Some(9),
                window: None,
            }))
            .collect();
        let d = Dataset {
            kind: DataKind::Flaws,
            root: PathBuf::new(),
            classes: vec!["control".into(), "flaw".into()],
            normal: "control".into(),
            items,
            pixel_mm: Some(0.1),
        };
        let parts = d.split(0.2);
        assert_eq!(&parts[8..], &[Part::Val, Part::Val, Part::Val]);
        assert_eq!(parts[7], Part::Dropped);
        assert_eq!(
            parts[2],
            Part::Dropped,
            "flaw 9 is in the validation layers"
        );
        assert_eq!(parts[1], Part::Train);
    }
}
