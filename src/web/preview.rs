//! The pictures of the page: each view of a layer rectified onto the build grid (through the
//! build's calibration) or the oblique original, at preview size or as a crop at full
//! resolution, encoded as JPEG. Encoded pictures are kept in a memory cache bounded in bytes;
//! the two most recently decoded originals are kept for zooming.

use super::files::{BuildFile, FileError, FileKind};
use crate::geometry::Grid;
use crate::rectify::{self, Calibration, Interpolation, Rectifier, RectifyError};
use axum::body::Bytes;
use image::DynamicImage;
use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::sync::{Arc, Mutex};

/// A picture's validator (its HTTP ETag): the original it is made of (device, inode, size and
/// modification time: a frame of another build, even at the same address, layer and view, is
/// another file), which part and kind, and what it is made with (`made_with`: the grid, the
/// calibration and the program, as [`super::state::BuildInfo`] says; `max_px`). The page's
/// pictures are sent `no-cache` with it, so a browser asks again (304 when nothing changed)
/// rather than keep showing a picture of another build or calibration. `None`: no such file.
pub fn validator(
    original: &Path,
    (kind, region): (Kind, Region),
    made_with: &str,
    max_px: u32,
) -> Option<String> {
    let m = std::fs::symlink_metadata(original).ok()?;
    let key = format!(
        "{}:{kind:?}:{region:?}:{made_with}:{max_px}",
        crate::fsutil::FileIdentity::of(&m)
    );
    Some(format!(
        "\"{}\"",
        &crate::fsutil::sha256_hex(key.as_bytes())[..32]
    ))
}

/// Which picture of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Kind {
    /// Top-down on the build grid, as the DICOM series holds it.
    Rectified,
    /// The camera's oblique frame.
    Raw,
}

/// A picture kind that is neither `rectified` nor `raw`.
#[derive(Debug, thiserror::Error)]
#[error("unknown kind '{0}': expected rectified or raw")]
pub struct UnknownKind(String);

impl std::str::FromStr for Kind {
    type Err = UnknownKind;
    fn from_str(s: &str) -> Result<Kind, UnknownKind> {
        match s {
            "rectified" => Ok(Kind::Rectified),
            "raw" => Ok(Kind::Raw),
            _ => Err(UnknownKind(s.to_string())),
        }
    }
}

/// A crop that is not inside the picture.
#[derive(Debug, thiserror::Error)]
#[error(
    "x, y, w, h are fractions of the picture: 0 ≤ x, y; w, h ≥ 0.0001; x + w ≤ 1 and y + h ≤ 1"
)]
pub struct RegionOutside;

/// A part of a picture as fractions of its width and height from its top left corner.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region {
    pub x: f64,
    pub y: f64,
    pub w: f64,
    pub h: f64,
}

impl Region {
    pub const WHOLE: Region = Region {
        x: 0.0,
        y: 0.0,
        w: 1.0,
        h: 1.0,
    };

    /// A region inside the picture, at least 1/10000 of it a side.
    pub fn checked(x: f64, y: f64, w: f64, h: f64) -> Result<Region, RegionOutside> {
        let ok = [x, y, w, h].iter().all(|v| v.is_finite())
            && x >= 0.0
            && y >= 0.0
            && w >= 1e-4
            && h >= 1e-4
            && x + w <= 1.0 + 1e-9
            && y + h <= 1.0 + 1e-9;
        ok.then_some(Region { x, y, w, h }).ok_or(RegionOutside)
    }

    fn key(&self) -> [u64; 4] {
        [self.x, self.y, self.w, self.h].map(f64::to_bits)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum PreviewError {
    #[error(
        "this build has no calibration (calibration.toml): only the original frames can be shown"
    )]
    NoCalibration,
    #[error(transparent)]
    File(#[from] FileError),
    /// The stored frame is not a picture this page can decode (damaged, truncated, crafted):
    /// the request is refused (422), the page goes on.
    #[error("{frame}: the frame cannot be decoded")]
    Decode {
        frame: String,
        #[source]
        source: RectifyError,
    },
    /// The build's calibration cannot rectify onto the requested grid.
    #[error(transparent)]
    Rectify(#[from] RectifyError),
    #[error("the crop is smaller than a pixel of the picture: zoom out")]
    TooSmall,
    #[error("cannot encode the picture")]
    Encode(#[source] image::ImageError),
}

/// What rectified pictures are made with: the build's calibration and grid.
pub struct Rectification {
    pub calibration: Calibration,
    pub grid: Grid,
}

/// The part of `grid` a region covers, with pixels no smaller than the grid's and at most
/// `max_px` a side.
pub fn region_grid(grid: &Grid, region: Region, max_px: u32) -> Grid {
    let (width, height) = (grid.x_max - grid.x_min, grid.y_max - grid.y_min);
    let x_min = grid.x_min + region.x * width;
    let y_max = grid.y_max - region.y * height;
    let (w, h) = (region.w * width, region.h * height);
    Grid {
        x_min,
        x_max: x_min + w,
        y_min: y_max - h,
        y_max,
        pixel_mm: grid.pixel_mm.max(w.max(h) / f64::from(max_px)),
    }
}

type CacheKey = (BuildFile, Kind, [u64; 4]);

/// Encoded pictures, bounded in bytes; the least recently used go first.
struct Cache {
    entries: BTreeMap<CacheKey, (Bytes, u64)>,
    bytes: usize,
    limit: usize,
    tick: u64,
}

impl Cache {
    fn get(&mut self, key: &CacheKey) -> Option<Bytes> {
        self.tick += 1;
        let tick = self.tick;
        self.entries.get_mut(key).map(|(bytes, used)| {
            *used = tick;
            bytes.clone()
        })
    }

    fn put(&mut self, key: CacheKey, bytes: Bytes) {
        if bytes.len() > self.limit {
            return;
        }
        self.tick += 1;
        self.bytes += bytes.len();
        if let Some((old, _)) = self.entries.insert(key, (bytes, self.tick)) {
            self.bytes -= old.len();
        }
        while self.bytes > self.limit {
            let oldest = self
                .entries
                .iter()
                .min_by_key(|(_, (_, used))| *used)
                .map(|(k, _)| k.clone());
            match oldest.and_then(|k| self.entries.remove(&k)) {
                Some((old, _)) => self.bytes -= old.len(),
                None => break,
            }
        }
    }
}

/// A decoded original, kept for the next crop of the same frame.
enum Decoded {
    Luma(rectify::FrameLuma),
    Colour(DynamicImage),
}

/// A decoded original and what it was decoded for.
type DecodedEntry = ((BuildFile, Kind), Arc<Decoded>);

/// Makes and keeps the page's pictures.
pub struct Pictures {
    max_px: u32,
    cache: Mutex<Cache>,
    decoded: Mutex<VecDeque<DecodedEntry>>,
}

impl Pictures {
    pub fn new(max_px: u32, cache_bytes: usize) -> Pictures {
        Pictures {
            max_px,
            cache: Mutex::new(Cache {
                entries: BTreeMap::new(),
                bytes: 0,
                limit: cache_bytes,
                tick: 0,
            }),
            decoded: Mutex::new(VecDeque::new()),
        }
    }

    /// Forgets every picture made (the calibration or grid they were made with changed).
    pub fn forget_all(&self) {
        let mut cache = lock(&self.cache);
        cache.entries.clear();
        cache.bytes = 0;
    }

    /// Whether the picture is cached already.
    pub fn cached(&self, original: &BuildFile, kind: Kind, region: Region) -> Option<Bytes> {
        let key = (original.clone(), kind, region.key());
        lock(&self.cache).get(&key)
    }

    /// The JPEG of `region` of the original's picture of `kind` (blocking: decodes and
    /// rectifies on the page's own thread pool; call it off the async runtime).
    pub fn picture(
        &self,
        original: &BuildFile,
        kind: Kind,
        region: Region,
        rectification: Option<&Rectification>,
    ) -> Result<Bytes, PreviewError> {
        if let Some(hit) = self.cached(original, kind, region) {
            return Ok(hit);
        }
        page_pool().install(|| self.make(original, kind, region, rectification))
    }

    fn make(
        &self,
        original: &BuildFile,
        kind: Kind,
        region: Region,
        rectification: Option<&Rectification>,
    ) -> Result<Bytes, PreviewError> {
        let decoded = self.decoded(original, kind)?;
        let picture = match (&*decoded, kind) {
            (Decoded::Luma(luma), Kind::Rectified) => {
                let r = rectification.ok_or(PreviewError::NoCalibration)?;
                let (columns, rows) = (r.grid.columns() as f64, r.grid.rows() as f64);
                if !covers_a_pixel(region, columns, rows) {
                    return Err(PreviewError::TooSmall);
                }
                let grid = region_grid(&r.grid, region, self.max_px);
                let rectifier =
                    Rectifier::new(&r.calibration.camera(), grid, Interpolation::Bilinear, 0)?;
                DynamicImage::ImageLuma8(luma.rectified(&rectifier).to_display8())
            }
            (Decoded::Colour(image), _) => {
                let (width, height) = (f64::from(image.width()), f64::from(image.height()));
                if !covers_a_pixel(region, width, height) {
                    return Err(PreviewError::TooSmall);
                }
                crop(image, region, self.max_px)
            }
            (Decoded::Luma(_), Kind::Raw) => unreachable!("raw pictures are decoded in colour"),
        };
        let mut jpeg = Vec::new();
        let rgb_or_gray = match picture {
            DynamicImage::ImageLuma8(_) | DynamicImage::ImageRgb8(_) => picture,
            other => DynamicImage::ImageRgb8(other.to_rgb8()),
        };
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 85)
            .encode_image(&rgb_or_gray)
            .map_err(PreviewError::Encode)?;
        let bytes = Bytes::from(jpeg);
        let key = (original.clone(), kind, region.key());
        lock(&self.cache).put(key, bytes.clone());
        Ok(bytes)
    }

    fn decoded(&self, original: &BuildFile, kind: Kind) -> Result<Arc<Decoded>, PreviewError> {
        let key = (original.clone(), kind);
        if let Some((_, hit)) = lock(&self.decoded).iter().find(|(k, _)| *k == key) {
            return Ok(hit.clone());
        }
        let bytes = original.read(FileKind::Frame)?;
        let undecodable = |source| PreviewError::Decode {
            frame: original.name(),
            source,
        };
        let decoded = Arc::new(match kind {
            Kind::Rectified => {
                Decoded::Luma(rectify::decode_frame_luma(&bytes).map_err(undecodable)?)
            }
            Kind::Raw => Decoded::Colour(rectify::decode_frame(&bytes).map_err(undecodable)?),
        });
        let mut kept = lock(&self.decoded);
        kept.push_front((key, decoded.clone()));
        kept.truncate(2);
        Ok(decoded)
    }
}

/// Whether `region` of a picture of `width` x `height` pixels is a pixel or more each way.
fn covers_a_pixel(region: Region, width: f64, height: f64) -> bool {
    region.w * width >= 1.0 - 1e-6 && region.h * height >= 1.0 - 1e-6
}

/// `region` of `image`, scaled down to at most `max_px` a side.
fn crop(image: &DynamicImage, region: Region, max_px: u32) -> DynamicImage {
    let (w, h) = (f64::from(image.width()), f64::from(image.height()));
    let x = (region.x * w).floor() as u32;
    let y = (region.y * h).floor() as u32;
    let cw = ((region.w * w).ceil() as u32).clamp(1, image.width() - x.min(image.width() - 1));
    let ch = ((region.h * h).ceil() as u32).clamp(1, image.height() - y.min(image.height() - 1));
    let part = image.crop_imm(x.min(image.width() - 1), y.min(image.height() - 1), cw, ch);
    if cw.max(ch) > max_px {
        part.thumbnail(max_px, max_px)
    } else {
        part
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The page's own rayon pool: decoding and rectifying a picture split over the global pool would
/// queue the processing worker's rows behind the page's (measured: processing p90 5x longer with
/// five clients open). One thread at nice +10, so a picture never takes more than what capture
/// and processing leave.
fn page_pool() -> &'static rayon::ThreadPool {
    static POOL: std::sync::OnceLock<rayon::ThreadPool> = std::sync::OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .thread_name(|_| "layerwise-web-pictures".into())
            .start_handler(|_| super::priority::lower_priority())
            .build()
            .unwrap_or_else(|_| {
                // Without a thread of its own the page shares the global pool, as before.
                rayon::ThreadPoolBuilder::new()
                    .use_current_thread()
                    .num_threads(1)
                    .build()
                    .expect("a pool on the current thread needs no new thread")
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_are_checked_and_map_to_grids_of_bounded_size() {
        assert!(Region::checked(0.5, 0.5, 0.6, 0.1).is_err());
        assert!(Region::checked(f64::NAN, 0.0, 0.1, 0.1).is_err());
        assert!(Region::checked(0.0, 0.0, 0.0, 0.1).is_err());
        let grid = Grid::plate();
        let whole = region_grid(&grid, Region::WHOLE, 1000);
        assert_eq!((whole.columns(), whole.rows()), (1000, 1000));
        // A small crop keeps the grid's own pixels: full resolution.
        let crop = region_grid(&grid, Region::checked(0.5, 0.25, 0.1, 0.05).unwrap(), 1000);
        assert_eq!(crop.pixel_mm, grid.pixel_mm);
        assert_eq!((crop.columns(), crop.rows()), (440, 220));
        assert!((crop.x_min - 0.0).abs() < 1e-9 && (crop.y_max - 68.75).abs() < 1e-9);
    }

    #[test]
    fn the_cache_keeps_within_its_bytes_dropping_the_least_recently_used() {
        let pictures = Pictures::new(64, 10);
        let mut cache = lock(&pictures.cache);
        let key = |n: u8| {
            (
                BuildFile::new(Path::new("build"), &[&format!("{n}")]),
                Kind::Raw,
                Region::WHOLE.key(),
            )
        };
        cache.put(key(1), Bytes::from(vec![0; 4]));
        cache.put(key(2), Bytes::from(vec![0; 4]));
        assert!(cache.get(&key(1)).is_some());
        cache.put(key(3), Bytes::from(vec![0; 4]));
        assert!(cache.get(&key(2)).is_none() && cache.get(&key(1)).is_some());
        assert!(cache.bytes <= 10);
        cache.put(key(4), Bytes::from(vec![0; 11]));
        assert!(cache.get(&key(4)).is_none(), "larger than the whole cache");
    }
}
