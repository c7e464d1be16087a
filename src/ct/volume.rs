//! CT volumes and their readers: GE phoenix `.vol` + `.pcr`, VGStudio `.vgi`, explicit raw, TIFF
//! stacks and (feature-free) DICOM series.
//!
//! Voxels keep their stored type (a 1024³ u16 volume is 2 GiB, not 4 as f32) and raw files are
//! read slice by slice, so peak memory is the volume plus one slice.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::{io_err, CtError, Result};

/// Voxel values in their stored type; `Volume::rescale` maps them to physical units.
#[derive(Debug, Clone, PartialEq)]
pub enum VoxelData {
    U8(Vec<u8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    F32(Vec<f32>),
}

impl VoxelData {
    pub fn len(&self) -> usize {
        match self {
            VoxelData::U8(v) => v.len(),
            VoxelData::U16(v) => v.len(),
            VoxelData::I16(v) => v.len(),
            VoxelData::F32(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A stored voxel type.
pub trait Voxel: Copy + Send + Sync + 'static {
    fn to_f32(self) -> f32;
}
impl Voxel for u8 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
impl Voxel for u16 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
impl Voxel for i16 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
impl Voxel for f32 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
}

/// Run a generic body on the stored slice, whatever its type.
macro_rules! with_voxels {
    ($data:expr, $v:ident => $body:expr) => {
        match $data {
            $crate::ct::volume::VoxelData::U8($v) => $body,
            $crate::ct::volume::VoxelData::U16($v) => $body,
            $crate::ct::volume::VoxelData::I16($v) => $body,
            $crate::ct::volume::VoxelData::F32($v) => $body,
        }
    };
}
pub(crate) use with_voxels;

/// A CT volume: x (column) fastest, then y (row), then z (slice).
#[derive(Debug, Clone)]
pub struct Volume {
    pub dims: [usize; 3],
    /// Spacing along the index axes, mm.
    pub voxel_mm: [f64; 3],
    /// Voxel index (i, j, k, 1) → CT physical mm (DICOM patient coordinates, or index × voxel
    /// size for raw volumes).
    pub index_to_mm: [[f64; 4]; 4],
    pub data: VoxelData,
    /// Physical value = stored × slope + intercept (DICOM RescaleSlope/Intercept; 1, 0 else).
    pub rescale_slope: f64,
    pub rescale_intercept: f64,
}

impl Volume {
    /// A volume whose physical coordinates are index × voxel size (raw files, TIFF stacks).
    pub fn new_scaled(dims: [usize; 3], voxel_mm: [f64; 3], data: VoxelData) -> Result<Self> {
        let n = dims[0]
            .checked_mul(dims[1])
            .and_then(|v| v.checked_mul(dims[2]))
            .ok_or_else(|| CtError::Invalid(format!("volume dims {dims:?} overflow")))?;
        if n != data.len() {
            return Err(CtError::Invalid(format!(
                "volume dims {dims:?} need {n} voxels, data has {}",
                data.len()
            )));
        }
        if voxel_mm.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(CtError::Invalid(format!(
                "voxel size {voxel_mm:?} mm must be positive"
            )));
        }
        let mut m = [[0.0; 4]; 4];
        for a in 0..3 {
            m[a][a] = voxel_mm[a];
        }
        m[3][3] = 1.0;
        Ok(Self {
            dims,
            voxel_mm,
            index_to_mm: m,
            data,
            rescale_slope: 1.0,
            rescale_intercept: 0.0,
        })
    }

    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Physical value of voxel `i` (linear index).
    pub fn value(&self, i: usize) -> f64 {
        let raw = with_voxels!(&self.data, v => v[i].to_f32()) as f64;
        raw * self.rescale_slope + self.rescale_intercept
    }

    /// Continuous voxel index → CT physical mm.
    pub fn index_to_physical(&self, p: [f64; 3]) -> [f64; 3] {
        let m = &self.index_to_mm;
        std::array::from_fn(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
    }

    /// Smallest and largest physical value.
    pub fn value_range(&self) -> (f64, f64) {
        use rayon::prelude::*;
        let (lo, hi) = with_voxels!(&self.data, v => v
            .par_chunks(1 << 16)
            .map(|c| c.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), x| {
                let x = x.to_f32();
                (lo.min(x), hi.max(x))
            }))
            .reduce(|| (f32::INFINITY, f32::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1))));
        let a = lo as f64 * self.rescale_slope + self.rescale_intercept;
        let b = hi as f64 * self.rescale_slope + self.rescale_intercept;
        (a.min(b), a.max(b))
    }
}

/// Stored type of a raw volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawDtype {
    U8,
    U16,
    I16,
    F32,
}

impl RawDtype {
    pub fn bytes(self) -> usize {
        match self {
            RawDtype::U8 => 1,
            RawDtype::U16 | RawDtype::I16 => 2,
            RawDtype::F32 => 4,
        }
    }

    /// `u8`, `u16`, `i16` or `f32` (the `--dtype` option).
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "u8" | "uint8" => Some(RawDtype::U8),
            "u16" | "uint16" => Some(RawDtype::U16),
            "i16" | "int16" => Some(RawDtype::I16),
            "f32" | "float32" | "float" => Some(RawDtype::F32),
            _ => None,
        }
    }
}

/// A headerless little-endian raw volume: x fastest, then y, then z.
#[derive(Debug, Clone, PartialEq)]
pub struct RawSpec {
    pub dims: [usize; 3],
    pub voxel_mm: [f64; 3],
    pub dtype: RawDtype,
    /// Bytes to skip at the start of the file.
    pub header_bytes: u64,
}

impl RawSpec {
    /// From the command line: `--size X,Y,Z --voxel-mm S --dtype u8|u16|f32`.
    pub fn from_args(size: &str, voxel_mm: f64, dtype: &str) -> Result<Self> {
        let parts: Vec<&str> = size
            .split([',', 'x', ' '])
            .filter(|s| !s.is_empty())
            .collect();
        let dims: Vec<usize> = parts.iter().filter_map(|s| s.trim().parse().ok()).collect();
        if parts.len() != 3 || dims.len() != 3 || dims.contains(&0) {
            return Err(CtError::Invalid(format!(
                "--size {size:?}: expected three positive integers X,Y,Z"
            )));
        }
        let dtype = RawDtype::parse(dtype).ok_or_else(|| {
            CtError::Invalid(format!("--dtype {dtype:?}: expected u8, u16, i16 or f32"))
        })?;
        if !(voxel_mm.is_finite() && voxel_mm > 0.0) {
            return Err(CtError::Invalid(format!(
                "--voxel-mm {voxel_mm}: must be positive"
            )));
        }
        Ok(Self {
            dims: [dims[0], dims[1], dims[2]],
            voxel_mm: [voxel_mm; 3],
            dtype,
            header_bytes: 0,
        })
    }
}

/// Read a raw volume, one slice at a time.
pub fn read_raw(path: &Path, spec: &RawSpec) -> Result<Volume> {
    let [nx, ny, nz] = spec.dims;
    let bpv = spec.dtype.bytes();
    let slice_bytes = nx
        .checked_mul(ny)
        .and_then(|v| v.checked_mul(bpv))
        .ok_or_else(|| CtError::Invalid(format!("dims {:?} overflow", spec.dims)))?;
    let expected = spec.header_bytes + (slice_bytes as u64) * nz as u64;
    let file = File::open(path).map_err(io_err(path))?;
    let actual = file.metadata().map_err(io_err(path))?.len();
    if actual != expected {
        return Err(CtError::SizeMismatch {
            path: path.to_path_buf(),
            dims: spec.dims,
            bytes_per_voxel: bpv,
            header: spec.header_bytes,
            expected,
            actual,
        });
    }
    let mut reader = BufReader::with_capacity(1 << 20, file);
    reader
        .seek(SeekFrom::Start(spec.header_bytes))
        .map_err(io_err(path))?;
    let n = nx * ny * nz;
    let mut buf = vec![0u8; slice_bytes];
    // Decode each slice into the final vector: no full-size byte copy.
    macro_rules! read_as {
        ($t:ty, $variant:ident) => {{
            let mut out: Vec<$t> = Vec::with_capacity(n);
            for _ in 0..nz {
                reader.read_exact(&mut buf).map_err(io_err(path))?;
                out.extend(
                    buf.chunks_exact(std::mem::size_of::<$t>())
                        .map(|c| <$t>::from_le_bytes(c.try_into().unwrap_or_default())),
                );
            }
            VoxelData::$variant(out)
        }};
    }
    let data = match spec.dtype {
        RawDtype::U8 => read_as!(u8, U8),
        RawDtype::U16 => read_as!(u16, U16),
        RawDtype::I16 => read_as!(i16, I16),
        RawDtype::F32 => read_as!(f32, F32),
    };
    Volume::new_scaled(spec.dims, spec.voxel_mm, data)
}

/// A parsed INI-like header: `[section]` then `key = value`; names are case-insensitive.
struct Ini {
    path: PathBuf,
    /// (section, key) → value, lower-case names.
    entries: HashMap<(String, String), String>,
}

impl Ini {
    fn read(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(io_err(path))?;
        // Headers written on Windows may be Latin-1: accept any bytes.
        let text = String::from_utf8_lossy(&bytes);
        let mut section = String::new();
        let mut entries = HashMap::new();
        for line in text.lines() {
            let line = line.trim();
            if line.is_empty() || line.starts_with(';') || line.starts_with('#') {
                continue;
            }
            if line.starts_with('[') && line.ends_with(']') {
                section = line[1..line.len() - 1].trim().to_ascii_lowercase();
                continue;
            }
            if line.starts_with('{') {
                // VGStudio `{volume1}` blocks: the sections below are what matter.
                continue;
            }
            if let Some((k, v)) = line.split_once('=') {
                entries
                    .entry((section.clone(), k.trim().to_ascii_lowercase()))
                    .or_insert_with(|| v.trim().to_string());
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            entries,
        })
    }

    fn get(&self, section: &str, key: &str) -> Option<&str> {
        self.entries
            .get(&(section.to_string(), key.to_ascii_lowercase()))
            .map(String::as_str)
    }

    /// The key in `section`, or in any section when it moved between software versions.
    fn get_any(&self, section: &str, key: &str) -> Option<&str> {
        self.get(section, key).or_else(|| {
            let key = key.to_ascii_lowercase();
            let mut hits: Vec<_> = self
                .entries
                .iter()
                .filter(|((_, k), _)| *k == key)
                .collect();
            hits.sort_by(|a, b| a.0.cmp(b.0));
            hits.first().map(|(_, v)| v.as_str())
        })
    }

    fn require(&self, section: &str, key: &str) -> Result<&str> {
        self.get_any(section, key)
            .ok_or_else(|| CtError::MissingKey {
                path: self.path.clone(),
                section: section.to_string(),
                key: key.to_string(),
            })
    }

    fn bad(&self, key: &str, value: &str, reason: &str) -> CtError {
        CtError::BadValue {
            path: self.path.clone(),
            key: key.to_string(),
            value: value.to_string(),
            reason: reason.to_string(),
        }
    }

    fn number<T: std::str::FromStr>(&self, section: &str, key: &str) -> Result<T> {
        let v = self.require(section, key)?;
        v.parse().map_err(|_| self.bad(key, v, "not a number"))
    }

    fn numbers(&self, section: &str, key: &str, n: usize) -> Result<Vec<f64>> {
        let v = self.require(section, key)?;
        let xs: Vec<f64> = v
            .split_whitespace()
            .map(str::parse)
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| self.bad(key, v, "not a list of numbers"))?;
        if xs.len() < n {
            return Err(self.bad(key, v, &format!("expected {n} numbers")));
        }
        Ok(xs)
    }
}

/// The `.vol` next to a `.pcr` (or the `.pcr` next to a `.vol`).
fn sibling(path: &Path, ext: &str) -> PathBuf {
    path.with_extension(ext)
}

/// Read a GE phoenix volume: `path` is the `.pcr` or the `.vol`.
pub fn read_phoenix(path: &Path) -> Result<Volume> {
    let is_pcr = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("pcr"));
    let (pcr, vol) = if is_pcr {
        (path.to_path_buf(), sibling(path, "vol"))
    } else {
        (sibling(path, "pcr"), path.to_path_buf())
    };
    let spec = phoenix_spec(&pcr)?;
    read_raw(&vol, &spec)
}

/// The raw layout described by a phoenix `.pcr`.
pub fn phoenix_spec(pcr: &Path) -> Result<RawSpec> {
    let ini = Ini::read(pcr)?;
    let s = "volumedata";
    let dims = [
        ini.number::<usize>(s, "Volume_SizeX")?,
        ini.number::<usize>(s, "Volume_SizeY")?,
        ini.number::<usize>(s, "Volume_SizeZ")?,
    ];
    let voxel: f64 = ini.number(s, "VoxelSizeRec")?;
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(ini.bad("VoxelSizeRec", &voxel.to_string(), "must be positive mm"));
    }
    let format = ini.require(s, "Format")?;
    let dtype = match format.trim() {
        "1" | "3" => RawDtype::U8,
        "5" => RawDtype::U16,
        "10" => RawDtype::F32,
        other => {
            return Err(CtError::UnknownDtype {
                path: pcr.to_path_buf(),
                dtype: format!("Format={other}"),
                expected: "Format 1 or 3 (8-bit), 5 (16-bit), 10 (float)",
            })
        }
    };
    if dims.contains(&0) {
        return Err(ini.bad("Volume_SizeX/Y/Z", &format!("{dims:?}"), "must be positive"));
    }
    Ok(RawSpec {
        dims,
        voxel_mm: [voxel; 3],
        dtype,
        header_bytes: 0,
    })
}

/// Read a VGStudio `.vgi` and the raw file it names.
pub fn read_vgi(path: &Path) -> Result<Volume> {
    let (raw, spec) = vgi_spec(path)?;
    read_raw(&raw, &spec)
}

/// The raw file and layout a `.vgi` describes.
pub fn vgi_spec(path: &Path) -> Result<(PathBuf, RawSpec)> {
    let ini = Ini::read(path)?;
    let size = ini.numbers("file1", "Size", 3)?;
    let dims = [size[0] as usize, size[1] as usize, size[2] as usize];
    if size.iter().take(3).any(|v| *v < 1.0 || v.fract() != 0.0) {
        return Err(ini.bad(
            "Size",
            ini.require("file1", "Size")?,
            "expected 3 positive integers",
        ));
    }
    let res = ini.numbers("geometry", "resolution", 1)?;
    let voxel_mm = if res.len() >= 3 {
        [res[0], res[1], res[2]]
    } else {
        [res[0]; 3]
    };
    if voxel_mm.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(ini.bad("resolution", &format!("{res:?}"), "must be positive mm"));
    }
    let dt = ini.require("file1", "Datatype")?.to_ascii_lowercase();
    let bits: u32 = ini.number("file1", "BitsPerElement")?;
    let float = dt.contains("float") || dt.contains("real");
    let signed = dt.contains("signed") && !dt.contains("unsigned");
    let dtype = match (float, signed, bits) {
        (true, _, 32) => RawDtype::F32,
        (false, false, 8) => RawDtype::U8,
        (false, false, 16) => RawDtype::U16,
        (false, true, 16) => RawDtype::I16,
        _ => {
            return Err(CtError::UnknownDtype {
                path: path.to_path_buf(),
                dtype: format!("Datatype={dt}, BitsPerElement={bits}"),
                expected: "unsigned 8/16-bit, signed 16-bit or 32-bit float",
            })
        }
    };
    let header_bytes = match ini.get("file1", "SkipHeader") {
        Some(v) => v
            .parse()
            .map_err(|_| ini.bad("SkipHeader", v, "not a byte count"))?,
        None => 0,
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let raw = match ini.get("file1", "Name") {
        // The name is relative to the .vgi, possibly written with Windows separators.
        Some(name) => {
            let name = name.trim_matches('"').replace('\\', "/");
            let file = Path::new(&name).file_name().map(PathBuf::from);
            let direct = dir.join(&name);
            match file {
                Some(f) if !direct.exists() => dir.join(f),
                _ => direct,
            }
        }
        None => {
            let vol = path.with_extension("vol");
            if vol.exists() {
                vol
            } else {
                path.with_extension("raw")
            }
        }
    };
    Ok((
        raw,
        RawSpec {
            dims,
            voxel_mm,
            dtype,
            header_bytes,
        },
    ))
}

/// Read a folder of `.tif`/`.tiff` slices sorted by name (slice k at z = k × voxel).
pub fn read_tiff_stack(dir: &Path, voxel_mm: [f64; 3]) -> Result<Volume> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io_err(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(CtError::Format {
            path: dir.to_path_buf(),
            message: "no .tif/.tiff files in the folder".into(),
        });
    }
    let mut data: Option<VoxelData> = None;
    let mut wh = (0u32, 0u32);
    for (k, f) in files.iter().enumerate() {
        let img = image::ImageReader::open(f)
            .map_err(io_err(f))?
            .with_guessed_format()
            .map_err(io_err(f))?
            .decode()
            .map_err(|e| CtError::Format {
                path: f.clone(),
                message: e.to_string(),
            })?;
        let size = (img.width(), img.height());
        if k == 0 {
            wh = size;
            let n = size.0 as usize * size.1 as usize * files.len();
            data = Some(match &img {
                image::DynamicImage::ImageLuma8(_) => VoxelData::U8(Vec::with_capacity(n)),
                image::DynamicImage::ImageLuma16(_) => VoxelData::U16(Vec::with_capacity(n)),
                _ => VoxelData::F32(Vec::with_capacity(n)),
            });
        } else if size != wh {
            return Err(CtError::Format {
                path: f.clone(),
                message: format!(
                    "slice is {}x{} but the first slice is {}x{}",
                    size.0, size.1, wh.0, wh.1
                ),
            });
        }
        match data.as_mut() {
            Some(VoxelData::U8(v)) => v.extend_from_slice(img.to_luma8().as_raw()),
            Some(VoxelData::U16(v)) => v.extend_from_slice(img.to_luma16().as_raw()),
            Some(VoxelData::F32(v)) => v.extend_from_slice(img.to_luma32f().as_raw()),
            _ => {}
        }
    }
    let data = data.unwrap_or(VoxelData::U8(Vec::new()));
    Volume::new_scaled([wh.0 as usize, wh.1 as usize, files.len()], voxel_mm, data)
}

/// Where a CT volume comes from (what the command line names).
#[derive(Debug, Clone, PartialEq)]
pub enum VolumeSource {
    /// GE phoenix `.pcr` or `.vol` (the other is found beside it).
    Phoenix(PathBuf),
    /// VGStudio `.vgi` and the raw file it names.
    Vgi(PathBuf),
    /// Headerless raw with an explicit layout (`--size --voxel-mm --dtype`).
    Raw(PathBuf, RawSpec),
    /// Folder of `.tif` slices with an isotropic voxel size in mm.
    Tiff(PathBuf, f64),
    /// Folder holding one DICOM series.
    Dicom(PathBuf),
}

impl VolumeSource {
    /// Guess from a path: `.pcr`/`.vol` → phoenix, `.vgi` → VGStudio, a folder with `.tif` files
    /// → TIFF stack (needs `voxel_mm`), any other folder → DICOM.
    pub fn detect(path: &Path, voxel_mm: Option<f64>) -> Result<Self> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if path.is_dir() {
            let has_tiff = std::fs::read_dir(path).map_err(io_err(path))?.any(|e| {
                e.ok().is_some_and(|e| {
                    let p = e.path();
                    let x = p
                        .extension()
                        .map(|x| x.to_string_lossy().to_ascii_lowercase());
                    matches!(x.as_deref(), Some("tif" | "tiff"))
                })
            });
            return Ok(match (has_tiff, voxel_mm) {
                (true, Some(v)) => VolumeSource::Tiff(path.to_path_buf(), v),
                (true, None) => {
                    return Err(CtError::Invalid(format!(
                        "{}: a TIFF stack needs the voxel size (--voxel-mm)",
                        path.display()
                    )))
                }
                (false, _) => VolumeSource::Dicom(path.to_path_buf()),
            });
        }
        match ext.as_str() {
            "pcr" | "vol" => Ok(VolumeSource::Phoenix(path.to_path_buf())),
            "vgi" => Ok(VolumeSource::Vgi(path.to_path_buf())),
            _ => Err(CtError::Invalid(format!(
                "{}: not a .pcr/.vol/.vgi file or a folder; for other raw files give --size, \
                 --voxel-mm and --dtype",
                path.display()
            ))),
        }
    }
}

/// Read a CT volume from any supported source.
pub fn read_volume(source: &VolumeSource) -> Result<Volume> {
    match source {
        VolumeSource::Phoenix(p) => read_phoenix(p),
        VolumeSource::Vgi(p) => read_vgi(p),
        VolumeSource::Raw(p, spec) => read_raw(p, spec),
        VolumeSource::Tiff(p, v) => read_tiff_stack(p, [*v; 3]),
        VolumeSource::Dicom(p) => read_dicom_series(p),
    }
}

/// One slice's header, read without its pixels.
struct DicomSlice {
    path: PathBuf,
    position: [f64; 3],
    rows: usize,
    columns: usize,
    spacing: [f64; 2],
    orientation: [f64; 6],
    slope: f64,
    intercept: f64,
}

fn dicom_err(path: &Path, message: impl Into<String>) -> CtError {
    CtError::Format {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

type DicomObject = dicom_object::DefaultDicomObject;

fn dicom_numbers(
    obj: &DicomObject,
    path: &Path,
    tag: dicom_core::Tag,
    name: &str,
    n: usize,
) -> Result<Vec<f64>> {
    let e = obj.element(tag).map_err(|_| CtError::MissingKey {
        path: path.to_path_buf(),
        section: String::new(),
        key: name.to_string(),
    })?;
    let v = e
        .to_multi_float64()
        .map_err(|err| dicom_err(path, format!("{name}: {err}")))?;
    if v.len() < n || v.iter().any(|x| !x.is_finite()) {
        return Err(dicom_err(
            path,
            format!("{name} has {} values {v:?}, expected {n}", v.len()),
        ));
    }
    Ok(v)
}

fn dicom_optional(
    obj: &DicomObject,
    path: &Path,
    tag: dicom_core::Tag,
    name: &str,
    default: f64,
) -> Result<f64> {
    match obj.element_opt(tag).ok().flatten() {
        None => Ok(default),
        Some(e) if dicom_core::header::HasLength::is_empty(e) => Ok(default),
        Some(e) => e
            .to_float64()
            .map_err(|err| dicom_err(path, format!("{name}: {err}"))),
    }
}

fn dicom_uint(obj: &DicomObject, path: &Path, tag: dicom_core::Tag, name: &str) -> Result<usize> {
    obj.element(tag)
        .map_err(|_| CtError::MissingKey {
            path: path.to_path_buf(),
            section: String::new(),
            key: name.to_string(),
        })?
        .to_int::<u32>()
        .map(|v| v as usize)
        .map_err(|err| dicom_err(path, format!("{name}: {err}")))
}

/// Read a folder holding one DICOM CT series (one slice per file, any orientation).
///
/// Geometry from ImagePositionPatient, ImageOrientationPatient and PixelSpacing; the slice axis
/// is the step between consecutive positions (so gantry tilt is kept) and must be uniform.
/// Values are RescaleSlope × stored + RescaleIntercept.
pub fn read_dicom_series(dir: &Path) -> Result<Volume> {
    use dicom_dictionary_std::tags;
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io_err(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    entries.sort();
    // Pass 1: headers only, to order the slices.
    let mut slices = Vec::new();
    for path in entries {
        let Ok(obj) = dicom_object::OpenFileOptions::new()
            .read_until(tags::PIXEL_DATA)
            .open_file(&path)
        else {
            // Not a DICOM file (a DICOMDIR's companions, notes, thumbnails): skip it.
            continue;
        };
        if obj.element_opt(tags::ROWS).ok().flatten().is_none() {
            continue; // no image (e.g. a DICOMDIR or a structured report)
        }
        if dicom_optional(&obj, &path, tags::NUMBER_OF_FRAMES, "NumberOfFrames", 1.0)? > 1.0 {
            return Err(dicom_err(
                &path,
                "multi-frame DICOM is not supported: export one slice per file",
            ));
        }
        let position = dicom_numbers(
            &obj,
            &path,
            tags::IMAGE_POSITION_PATIENT,
            "ImagePositionPatient",
            3,
        )?;
        let orientation = dicom_numbers(
            &obj,
            &path,
            tags::IMAGE_ORIENTATION_PATIENT,
            "ImageOrientationPatient",
            6,
        )?;
        let spacing = dicom_numbers(&obj, &path, tags::PIXEL_SPACING, "PixelSpacing", 2)?;
        slices.push(DicomSlice {
            rows: dicom_uint(&obj, &path, tags::ROWS, "Rows")?,
            columns: dicom_uint(&obj, &path, tags::COLUMNS, "Columns")?,
            position: [position[0], position[1], position[2]],
            spacing: [spacing[0], spacing[1]],
            orientation: std::array::from_fn(|i| orientation[i]),
            slope: dicom_optional(&obj, &path, tags::RESCALE_SLOPE, "RescaleSlope", 1.0)?,
            intercept: dicom_optional(
                &obj,
                &path,
                tags::RESCALE_INTERCEPT,
                "RescaleIntercept",
                0.0,
            )?,
            path,
        });
    }
    let Some(first) = slices.first() else {
        return Err(dicom_err(dir, "no DICOM image in the folder"));
    };
    let o = first.orientation;
    let row = nalgebra::Vector3::new(o[0], o[1], o[2]);
    let col = nalgebra::Vector3::new(o[3], o[4], o[5]);
    let normal = row.cross(&col);
    if (row.norm() - 1.0).abs() > 1e-3
        || (col.norm() - 1.0).abs() > 1e-3
        || row.dot(&col).abs() > 1e-3
    {
        return Err(dicom_err(
            &first.path,
            format!("ImageOrientationPatient {o:?} is not two orthonormal vectors"),
        ));
    }
    let (rows, columns, spacing) = (first.rows, first.columns, first.spacing);
    for s in &slices {
        let same_orientation = s
            .orientation
            .iter()
            .zip(&o)
            .all(|(a, b)| (a - b).abs() < 1e-4);
        if s.rows != rows || s.columns != columns || !same_orientation || s.spacing != spacing {
            return Err(dicom_err(
                &s.path,
                format!(
                    "slice is {}x{} at spacing {:?}, orientation {:?}; the first slice ({}) is \
                     {}x{} at {:?}, {:?}: not one series",
                    s.columns,
                    s.rows,
                    s.spacing,
                    s.orientation,
                    first.path.display(),
                    columns,
                    rows,
                    spacing,
                    o
                ),
            ));
        }
    }
    let proj = |s: &DicomSlice| normal.dot(&nalgebra::Vector3::from(s.position));
    slices.sort_by(|a, b| proj(a).total_cmp(&proj(b)));
    for w in slices.windows(2) {
        if (proj(&w[1]) - proj(&w[0])).abs() < 1e-6 {
            return Err(dicom_err(
                &w[1].path,
                format!("same slice position as {}", w[0].path.display()),
            ));
        }
    }
    let nz = slices.len();
    let p0 = nalgebra::Vector3::from(slices[0].position);
    let step = if nz > 1 {
        (nalgebra::Vector3::from(slices[nz - 1].position) - p0) / (nz - 1) as f64
    } else {
        // A single slice: unit thickness along the normal.
        normal * spacing[0]
    };
    let dz = step.norm();
    for (k, s) in slices.iter().enumerate() {
        let expect = p0 + step * k as f64;
        if (nalgebra::Vector3::from(s.position) - expect).norm() > 0.01 * dz {
            return Err(dicom_err(
                &s.path,
                format!(
                    "non-uniform slice spacing: slice {k} is at {:?}, expected {:?}",
                    s.position,
                    [expect.x, expect.y, expect.z]
                ),
            ));
        }
    }
    // Index (i = column, j = row, k = slice) → patient mm. PixelSpacing is [row spacing
    // (between rows, along the column direction), column spacing].
    let ex = row * spacing[1];
    let ey = col * spacing[0];
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        m[r] = [ex[r], ey[r], step[r], p0[r]];
    }
    m[3][3] = 1.0;

    // Pass 2: pixels in slice order, appended to one typed vector.
    let uniform_rescale = slices
        .iter()
        .all(|s| s.slope == slices[0].slope && s.intercept == slices[0].intercept);
    let n = rows * columns;
    let mut data: Option<VoxelData> = None;
    for s in &slices {
        use dicom_pixeldata::PixelDecoder;
        let obj =
            dicom_object::open_file(&s.path).map_err(|e| dicom_err(&s.path, e.to_string()))?;
        let px = obj
            .decode_pixel_data()
            .map_err(|e| dicom_err(&s.path, format!("cannot decode the pixel data: {e}")))?;
        let bits = px.bits_allocated();
        let signed = matches!(
            px.pixel_representation(),
            dicom_pixeldata::PixelRepresentation::Signed
        );
        if px.samples_per_pixel() != 1 {
            return Err(dicom_err(&s.path, "not a grayscale image"));
        }
        let bytes = px.data();
        if bytes.len() < n * (bits as usize / 8).max(1) {
            return Err(dicom_err(
                &s.path,
                format!(
                    "pixel data is {} bytes for {columns}x{rows} pixels of {bits} bits",
                    bytes.len()
                ),
            ));
        }
        let stored = px.bits_stored().clamp(1, 16) as u32;
        // Sign-extend signed values stored in fewer bits than allocated.
        let sext = |v: u16| -> i16 {
            let shift = 16 - stored;
            ((v << shift) as i16) >> shift
        };
        let slice_vals: VoxelData = match (bits, signed) {
            (8, false) => VoxelData::U8(bytes[..n].to_vec()),
            (16, false) => VoxelData::U16(
                bytes[..2 * n]
                    .chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]))
                    .collect(),
            ),
            (16, true) => VoxelData::I16(
                bytes[..2 * n]
                    .chunks_exact(2)
                    .map(|c| sext(u16::from_le_bytes([c[0], c[1]])))
                    .collect(),
            ),
            _ => {
                return Err(CtError::UnknownDtype {
                    path: s.path.clone(),
                    dtype: format!(
                        "BitsAllocated={bits}, PixelRepresentation={}",
                        if signed { 1 } else { 0 }
                    ),
                    expected: "8-bit unsigned or 16-bit pixels",
                })
            }
        };
        // Slices with their own rescale are converted to physical f32 values.
        let slice_vals = if uniform_rescale {
            slice_vals
        } else {
            let v: Vec<f32> = with_voxels!(&slice_vals, v => v.iter().map(|x| (x.to_f32() as f64 * s.slope + s.intercept) as f32).collect());
            VoxelData::F32(v)
        };
        let total = n * nz;
        let acc = data.get_or_insert_with(|| match &slice_vals {
            VoxelData::U8(_) => VoxelData::U8(Vec::with_capacity(total)),
            VoxelData::U16(_) => VoxelData::U16(Vec::with_capacity(total)),
            VoxelData::I16(_) => VoxelData::I16(Vec::with_capacity(total)),
            VoxelData::F32(_) => VoxelData::F32(Vec::with_capacity(total)),
        });
        match (acc, slice_vals) {
            (VoxelData::U8(a), VoxelData::U8(b)) => a.extend(b),
            (VoxelData::U16(a), VoxelData::U16(b)) => a.extend(b),
            (VoxelData::I16(a), VoxelData::I16(b)) => a.extend(b),
            (VoxelData::F32(a), VoxelData::F32(b)) => a.extend(b),
            _ => {
                return Err(dicom_err(
                    &s.path,
                    "pixel type differs from the first slice's",
                ))
            }
        }
    }
    let data = data.unwrap_or(VoxelData::U8(Vec::new()));
    let (slope, intercept) = if uniform_rescale {
        (slices[0].slope, slices[0].intercept)
    } else {
        (1.0, 0.0)
    };
    Ok(Volume {
        dims: [columns, rows, nz],
        voxel_mm: [spacing[1], spacing[0], dz],
        index_to_mm: m,
        data,
        rescale_slope: slope,
        rescale_intercept: intercept,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A fresh scratch folder for one test.
    pub(crate) fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("layerwise-ct-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("scratch dir");
        d
    }

    fn write_u16(path: &Path, n: usize) -> Vec<u16> {
        let v: Vec<u16> = (0..n).map(|i| (i * 7 % 65521) as u16).collect();
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        std::fs::write(path, bytes).expect("write raw");
        v
    }

    #[test]
    fn phoenix_pcr_and_vol() {
        let d = scratch("pcr");
        let v = write_u16(&d.join("part.vol"), 4 * 3 * 2);
        std::fs::write(
            d.join("part.pcr"),
            "[General]\nVersion=2\n[VolumeData]\nVolume_SizeX=4\nVolume_SizeY=3\nVolume_SizeZ=2\n\
             Format=5\nVoxelSizeRec=0.0421\n",
        )
        .expect("pcr");
        for p in [d.join("part.pcr"), d.join("part.vol")] {
            let vol = read_phoenix(&p).expect("read");
            assert_eq!(vol.dims, [4, 3, 2]);
            assert_eq!(vol.voxel_mm, [0.0421; 3]);
            assert_eq!(vol.data, VoxelData::U16(v.clone()));
            // x fastest: voxel (1, 2, 1) is element 1 + 4·2 + 12·1.
            assert_eq!(vol.value(1 + 4 * 2 + 12), v[21] as f64);
            assert_eq!(
                vol.index_to_physical([1.0, 2.0, 1.0]),
                [0.0421, 0.0842, 0.0421]
            );
        }
    }

    #[test]
    fn raw_size_mismatch_names_expected_and_actual_bytes() {
        let d = scratch("mismatch");
        write_u16(&d.join("part.vol"), 20);
        std::fs::write(
            d.join("part.pcr"),
            "[VolumeData]\nVolume_SizeX=4\nVolume_SizeY=3\nVolume_SizeZ=2\nFormat=5\nVoxelSizeRec=0.05\n",
        )
        .expect("pcr");
        let e = read_phoenix(&d.join("part.pcr")).expect_err("short file");
        let msg = e.to_string();
        assert!(msg.contains("part.vol"), "{msg}");
        assert!(
            msg.contains("is 40 bytes") && msg.contains("need 48 bytes"),
            "{msg}"
        );
    }

    #[test]
    fn pcr_missing_key_and_unknown_format() {
        let d = scratch("pcrkeys");
        std::fs::write(
            d.join("a.pcr"),
            "[VolumeData]\nVolume_SizeX=4\nVolume_SizeY=3\nFormat=5\nVoxelSizeRec=0.05\n",
        )
        .expect("pcr");
        let msg = phoenix_spec(&d.join("a.pcr"))
            .expect_err("no Z")
            .to_string();
        assert!(
            msg.contains("a.pcr") && msg.contains("Volume_SizeZ"),
            "{msg}"
        );
        std::fs::write(
            d.join("b.pcr"),
            "[VolumeData]\nVolume_SizeX=4\nVolume_SizeY=3\nVolume_SizeZ=2\nFormat=7\nVoxelSizeRec=0.05\n",
        )
        .expect("pcr");
        let e = phoenix_spec(&d.join("b.pcr")).expect_err("format 7");
        assert!(matches!(e, CtError::UnknownDtype { .. }), "{e}");
        assert!(e.to_string().contains("Format=7"), "{e}");
    }

    #[test]
    fn vgi_with_named_raw_file() {
        let d = scratch("vgi");
        let bytes: Vec<u8> = (0..24u32)
            .flat_map(|i| (i as f32 * 0.5).to_le_bytes())
            .collect();
        std::fs::write(d.join("scan.raw"), bytes).expect("raw");
        std::fs::write(
            d.join("scan.vgi"),
            "{volume1}\n[representation]\nsize = 4 3 2\n[file1]\nSkipHeader = 0\nFileFormat = raw\n\
             Size = 4 3 2\nName = C:\\data\\scan.raw\nDatatype = float\nBitsPerElement = 32\n\
             [geometry]\nstatus = ok\nresolution = 0.03 0.03 0.04\nunit = mm\n",
        )
        .expect("vgi");
        let vol = read_vgi(&d.join("scan.vgi")).expect("read");
        assert_eq!(vol.dims, [4, 3, 2]);
        assert_eq!(vol.voxel_mm, [0.03, 0.03, 0.04]);
        assert_eq!(vol.value(23), 11.5);
        std::fs::write(
            d.join("bad.vgi"),
            "[file1]\nSize = 4 3 2\nDatatype = complex\nBitsPerElement = 64\n[geometry]\nresolution = 0.03\n",
        )
        .expect("vgi");
        let e = vgi_spec(&d.join("bad.vgi")).expect_err("complex");
        assert!(matches!(e, CtError::UnknownDtype { .. }), "{e}");
    }

    #[test]
    fn detect_sources() {
        let d = scratch("detect");
        assert_eq!(
            VolumeSource::detect(&d.join("a.PCR"), None).expect("pcr"),
            VolumeSource::Phoenix(d.join("a.PCR"))
        );
        assert!(matches!(
            VolumeSource::detect(&d.join("a.vgi"), None),
            Ok(VolumeSource::Vgi(_))
        ));
        assert!(matches!(
            VolumeSource::detect(&d, None),
            Ok(VolumeSource::Dicom(_))
        ));
        std::fs::write(d.join("s0.tif"), b"x").expect("w");
        assert!(VolumeSource::detect(&d, None).is_err());
        assert!(matches!(
            VolumeSource::detect(&d, Some(0.05)),
            Ok(VolumeSource::Tiff(_, _))
        ));
        assert!(VolumeSource::detect(&d.join("a.raw"), None).is_err());
    }

    #[test]
    fn explicit_raw_spec() {
        let d = scratch("explicit");
        let v = write_u16(&d.join("x.raw"), 24);
        let spec = RawSpec::from_args("4,3,2", 0.1, "u16").expect("spec");
        let vol = read_raw(&d.join("x.raw"), &spec).expect("read");
        assert_eq!(vol.data, VoxelData::U16(v));
        assert!(RawSpec::from_args("4,3", 0.1, "u16").is_err());
        let msg = RawSpec::from_args("4,3,2", 0.1, "u12")
            .expect_err("u12")
            .to_string();
        assert!(msg.contains("u12"), "{msg}");
        let msg = read_raw(
            &d.join("x.raw"),
            &RawSpec::from_args("4,3,2", 0.1, "f32").expect("spec"),
        )
        .expect_err("f32 needs 96 bytes")
        .to_string();
        assert!(msg.contains("96") && msg.contains("48"), "{msg}");
    }

    #[test]
    fn tiff_stack_sorted_by_name() {
        let d = scratch("tiff");
        for (k, name) in [
            (1u16, "slice_002.tif"),
            (0, "slice_001.tif"),
            (2, "slice_010.tif"),
        ] {
            let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(5, 4, |x, y| {
                image::Luma([1000 * k + 10 * y as u16 + x as u16])
            });
            img.save(d.join(name)).expect("tiff");
        }
        std::fs::write(d.join("notes.txt"), "ignored").expect("txt");
        let vol = read_tiff_stack(&d, [0.05; 3]).expect("stack");
        assert_eq!(vol.dims, [5, 4, 3]);
        assert!(matches!(vol.data, VoxelData::U16(_)));
        // Voxel (3, 2, 2) comes from slice_010.tif.
        assert_eq!(vol.value(3 + 5 * 2 + 20 * 2), 2023.0);
        let small = image::ImageBuffer::<image::Luma<u16>, _>::new(3, 3);
        small.save(d.join("slice_011.tif")).expect("tiff");
        let msg = read_tiff_stack(&d, [0.05; 3])
            .expect_err("size")
            .to_string();
        assert!(
            msg.contains("slice_011.tif") && msg.contains("3x3"),
            "{msg}"
        );
    }
}
