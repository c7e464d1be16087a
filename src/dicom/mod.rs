//! DICOM series of a build, written with dicom-rs: every modality as the CT Image IOD (the paper's
//! choice: it carries the Image Plane module), in the build frame of docs/frames.md. One study and
//! one frame of reference per build; one series per view; one file per layer.

use crate::fsutil::write_atomic;
use dicom_core::value::{PrimitiveValue, C};
use dicom_core::{DataElement, Tag, VR};
use dicom_dictionary_std::tags;
use dicom_object::{FileMetaTableBuilder, InMemDicomObject, OpenFileOptions};
use dicom_pixeldata::Transcode;
use dicom_transfer_syntax_registry::TransferSyntaxIndex;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

// Element lengths checked against the file before a parser trusts them.
mod lengths;
pub mod uid;
pub use lengths::check_lengths;
pub use uid::{derived_uid, new_uid};

/// CT Image Storage.
pub const CT_IMAGE_STORAGE: &str = "1.2.840.10008.5.1.4.1.1.2";
/// Our implementation class UID (2.25 root, fixed for layerwise).
pub const IMPLEMENTATION_CLASS_UID: &str = "2.25.302378146212377404151786716384913425853";
const EXPLICIT_VR_LE: &str = "1.2.840.10008.1.2.1";
const JPEG_LS_LOSSLESS: &str = "1.2.840.10008.1.2.4.80";

/// Why a slice could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    #[error("{rows} x {columns} pixels cannot be a DICOM image (1 to 65535 each way)")]
    Size { rows: usize, columns: usize },
    #[error("{len} pixels for a {rows} x {columns} image")]
    PixelCount {
        len: usize,
        rows: usize,
        columns: usize,
    },
    #[error("{what}: {source}")]
    Encoder {
        what: &'static str,
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("this layerwise was built without JPEG-LS; rebuild with `--features jpegls` (needs cmake and g++) or choose deflate")]
    NoJpegLs,
}

impl EncodeError {
    fn encoder(
        what: &'static str,
    ) -> impl FnOnce(Box<dyn std::error::Error + Send + Sync>) -> EncodeError {
        move |source| EncodeError::Encoder { what, source }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum DicomError {
    #[error("{path}: {source}")]
    Encode { path: PathBuf, source: EncodeError },
    #[error(transparent)]
    Write(#[from] crate::fsutil::WriteError),
    #[error("{path}: not a readable DICOM file ({message}); if it was cut short by a crash, delete it and re-run")]
    Read { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Geometry { path: PathBuf, message: String },
    /// A stated length the file cannot hold (checked before any parser trusts it).
    #[error("{path}: {message}")]
    Damaged { path: PathBuf, message: String },
    #[error(
        "{path}: cannot search this folder ({source}); give an existing folder of DICOM files"
    )]
    Folder {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// How pixel data is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Compression {
    /// Explicit VR little endian: every viewer reads it.
    None,
    /// Deflated explicit VR little endian: the whole data set zlib-compressed.
    Deflate,
    /// JPEG-LS lossless (bit-exact), needs the `jpegls` feature.
    JpegLs,
}

/// The study a build is: fixed when the build starts.
#[derive(Clone, Debug, PartialEq)]
pub struct Study {
    pub study_instance_uid: String,
    pub frame_of_reference_uid: String,
    /// YYYYMMDD and HHMMSS of the build's start: one StudyDate/StudyTime for the whole build.
    pub date: String,
    pub time: String,
    pub patient_name: String,
    pub patient_id: String,
    pub study_id: String,
    pub description: String,
}

/// The build's name as a DICOM person name: the family-name component, explicitly delimited
/// (a bare single component is the retired PN form validators warn about).
pub fn person_name(name: &str) -> String {
    let clean: String = name
        .chars()
        .map(|c| {
            if matches!(c, '^' | '=' | '\\') {
                '_'
            } else {
                c
            }
        })
        .take(60)
        .collect();
    format!("{clean}^")
}

/// One series: a view of the build, the rasterized vectors, or the CT.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub series_instance_uid: String,
    pub number: u32,
    pub description: String,
}

impl Series {
    /// A series whose UID is derived from the study's and its name, so that every process writing
    /// it (the daemon before and after a restart, the exporter) agrees without shared state.
    pub fn named(study: &Study, number: u32, name: &str) -> Series {
        Series {
            series_instance_uid: derived_uid(&study.study_instance_uid, name),
            number,
            description: name.to_string(),
        }
    }
}

/// Where one slice sits in the build frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Build coordinates of the center of the top-left pixel (ImagePositionPatient).
    pub origin: [f64; 3],
    pub pixel_mm: f64,
    pub rows: usize,
    pub columns: usize,
    pub thickness_mm: f64,
}

/// One slice: the layer it shows and its pixels (16-bit, MONOCHROME2 as the CT IOD requires).
pub struct Slice<'a> {
    pub layer: u32,
    pub plane: Plane,
    pub pixels: &'a [u16],
    /// When the frame was taken (AcquisitionDate/Time, ContentDate/Time).
    pub acquired: Option<chrono::DateTime<chrono::Utc>>,
    /// Window for viewers: center and width.
    pub window: (f64, f64),
    /// How the pixels were made (DerivationDescription).
    pub derivation: &'a str,
}

fn put(obj: &mut InMemDicomObject, tag: Tag, vr: VR, value: impl Into<PrimitiveValue>) {
    obj.put(DataElement::new(tag, vr, value.into()));
}

fn put_empty(obj: &mut InMemDicomObject, tag: Tag, vr: VR) {
    obj.put(DataElement::new(tag, vr, PrimitiveValue::Empty));
}

fn ds(values: &[f64]) -> String {
    // DS is at most 16 characters per value.
    values
        .iter()
        .map(|v| format_ds(*v))
        .collect::<Vec<_>>()
        .join("\\")
}

fn format_ds(v: f64) -> String {
    let v = if v == 0.0 { 0.0 } else { v }; // no "-0"
    for precision in (0..=10).rev() {
        let s = format!("{v:.precision$}");
        let s = if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        };
        if s.len() <= 16 {
            return s;
        }
    }
    format!("{v:.6e}")
}

/// Builds the CT Image data set of one slice.
fn slice_object(
    study: &Study,
    series: &Series,
    slice: &Slice,
    sop_instance_uid: &str,
) -> InMemDicomObject {
    let mut o = InMemDicomObject::new_empty();
    let (acq_date, acq_time) = match slice.acquired {
        Some(t) => (
            t.format("%Y%m%d").to_string(),
            t.format("%H%M%S%.6f").to_string(),
        ),
        None => (study.date.clone(), study.time.clone()),
    };
    // SOP Common
    put(&mut o, tags::SPECIFIC_CHARACTER_SET, VR::CS, "ISO_IR 192");
    put(&mut o, tags::SOP_CLASS_UID, VR::UI, CT_IMAGE_STORAGE);
    put(&mut o, tags::SOP_INSTANCE_UID, VR::UI, sop_instance_uid);
    // Patient: the build stands in for the patient.
    put(
        &mut o,
        tags::PATIENT_NAME,
        VR::PN,
        study.patient_name.as_str(),
    );
    put(&mut o, tags::PATIENT_ID, VR::LO, study.patient_id.as_str());
    put_empty(&mut o, tags::PATIENT_BIRTH_DATE, VR::DA);
    put_empty(&mut o, tags::PATIENT_SEX, VR::CS);
    // General Study
    put(
        &mut o,
        tags::STUDY_INSTANCE_UID,
        VR::UI,
        study.study_instance_uid.as_str(),
    );
    put(&mut o, tags::STUDY_DATE, VR::DA, study.date.as_str());
    put(&mut o, tags::STUDY_TIME, VR::TM, study.time.as_str());
    put_empty(&mut o, tags::REFERRING_PHYSICIAN_NAME, VR::PN);
    put(&mut o, tags::STUDY_ID, VR::SH, study.study_id.as_str());
    put_empty(&mut o, tags::ACCESSION_NUMBER, VR::SH);
    put(
        &mut o,
        tags::STUDY_DESCRIPTION,
        VR::LO,
        study.description.as_str(),
    );
    // General Series
    put(&mut o, tags::MODALITY, VR::CS, "CT");
    put(
        &mut o,
        tags::SERIES_INSTANCE_UID,
        VR::UI,
        series.series_instance_uid.as_str(),
    );
    put(
        &mut o,
        tags::SERIES_NUMBER,
        VR::IS,
        series.number.to_string(),
    );
    put(
        &mut o,
        tags::SERIES_DESCRIPTION,
        VR::LO,
        series.description.as_str(),
    );
    put_empty(&mut o, tags::PATIENT_POSITION, VR::CS);
    // Frame of Reference
    put(
        &mut o,
        tags::FRAME_OF_REFERENCE_UID,
        VR::UI,
        study.frame_of_reference_uid.as_str(),
    );
    put_empty(&mut o, tags::POSITION_REFERENCE_INDICATOR, VR::LO);
    // General Equipment
    put(&mut o, tags::MANUFACTURER, VR::LO, "layerwise");
    put(
        &mut o,
        tags::SOFTWARE_VERSIONS,
        VR::LO,
        env!("CARGO_PKG_VERSION"),
    );
    // General Image
    put(
        &mut o,
        tags::INSTANCE_NUMBER,
        VR::IS,
        slice.layer.to_string(),
    );
    // DERIVED: the pixels are resampled (rectified, rasterized). dciodvfy also requires HU of
    // ORIGINAL images, and these are not Hounsfield units (RescaleType US).
    put(&mut o, tags::IMAGE_TYPE, VR::CS, "DERIVED\\PRIMARY\\AXIAL");
    put(
        &mut o,
        tags::DERIVATION_DESCRIPTION,
        VR::ST,
        slice.derivation,
    );
    put(&mut o, tags::CONTENT_DATE, VR::DA, acq_date.as_str());
    put(&mut o, tags::CONTENT_TIME, VR::TM, acq_time.as_str());
    put(&mut o, tags::ACQUISITION_DATE, VR::DA, acq_date.as_str());
    put(&mut o, tags::ACQUISITION_TIME, VR::TM, acq_time.as_str());
    put(&mut o, tags::ACQUISITION_NUMBER, VR::IS, "1");
    put(&mut o, tags::IMAGE_LATERALITY, VR::CS, "U");
    put(&mut o, tags::BURNED_IN_ANNOTATION, VR::CS, "NO");
    // Image Plane (docs/frames.md): rows run toward −y, columns toward +x.
    let p = slice.plane;
    put(
        &mut o,
        tags::PIXEL_SPACING,
        VR::DS,
        ds(&[p.pixel_mm, p.pixel_mm]),
    );
    put(
        &mut o,
        tags::IMAGE_ORIENTATION_PATIENT,
        VR::DS,
        ds(&[1.0, 0.0, 0.0, 0.0, -1.0, 0.0]),
    );
    put(&mut o, tags::IMAGE_POSITION_PATIENT, VR::DS, ds(&p.origin));
    put(&mut o, tags::SLICE_THICKNESS, VR::DS, ds(&[p.thickness_mm]));
    put(&mut o, tags::SLICE_LOCATION, VR::DS, ds(&[p.origin[2]]));
    // Image Pixel + CT Image
    put(
        &mut o,
        tags::SAMPLES_PER_PIXEL,
        VR::US,
        PrimitiveValue::from(1u16),
    );
    put(
        &mut o,
        tags::PHOTOMETRIC_INTERPRETATION,
        VR::CS,
        "MONOCHROME2",
    );
    put(
        &mut o,
        tags::ROWS,
        VR::US,
        PrimitiveValue::from(p.rows as u16),
    );
    put(
        &mut o,
        tags::COLUMNS,
        VR::US,
        PrimitiveValue::from(p.columns as u16),
    );
    put(
        &mut o,
        tags::BITS_ALLOCATED,
        VR::US,
        PrimitiveValue::from(16u16),
    );
    put(
        &mut o,
        tags::BITS_STORED,
        VR::US,
        PrimitiveValue::from(16u16),
    );
    put(&mut o, tags::HIGH_BIT, VR::US, PrimitiveValue::from(15u16));
    put(
        &mut o,
        tags::PIXEL_REPRESENTATION,
        VR::US,
        PrimitiveValue::from(0u16),
    );
    put(&mut o, tags::RESCALE_INTERCEPT, VR::DS, "0");
    put(&mut o, tags::RESCALE_SLOPE, VR::DS, "1");
    put(&mut o, tags::RESCALE_TYPE, VR::LO, "US");
    put_empty(&mut o, tags::KVP, VR::DS);
    put(&mut o, tags::WINDOW_CENTER, VR::DS, ds(&[slice.window.0]));
    put(&mut o, tags::WINDOW_WIDTH, VR::DS, ds(&[slice.window.1]));
    o.put(DataElement::new(
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::U16(C::from_vec(slice.pixels.to_vec())),
    ));
    o
}

/// The SOP instance UID of a layer of a series: stable, so rewriting a layer replaces it.
pub fn instance_uid(series: &Series, layer: u32) -> String {
    derived_uid(&series.series_instance_uid, &format!("L{layer}"))
}

/// The SOP instance UID of take `take` of a layer: take 1 (the frame) keeps [`instance_uid`], so
/// builds and archives keep their UIDs; a retake (take n > 1, `[series] take = "last"`) gets its
/// own, derived the same way, so an archive sees a replaced slice as a new instance.
pub fn instance_uid_of_take(series: &Series, layer: u32, take: u32) -> String {
    if take <= 1 {
        instance_uid(series, layer)
    } else {
        derived_uid(&series.series_instance_uid, &format!("L{layer}.r{take}"))
    }
}

/// Which stored original a slice was made from: its take (1: the frame, more: a retake) and
/// its file relative to the build directory (ImageComments says both).
#[derive(Clone, Copy, Debug)]
pub struct SliceSource<'a> {
    pub take: u32,
    pub file: &'a str,
}

impl SliceSource<'_> {
    /// The ImageComments text.
    pub fn comments(&self) -> String {
        format!("take {} of the layer's frame: {}", self.take, self.file)
    }
}

/// Encodes one slice as a DICOM file in memory.
pub fn encode_slice(
    study: &Study,
    series: &Series,
    slice: &Slice,
    compression: Compression,
) -> Result<Vec<u8>, EncodeError> {
    encode_slice_from(study, series, slice, compression, None)
}

/// Encodes one slice made from a stored original ([`SliceSource`]: its take picks the UID).
pub fn encode_slice_from(
    study: &Study,
    series: &Series,
    slice: &Slice,
    compression: Compression,
    source: Option<SliceSource>,
) -> Result<Vec<u8>, EncodeError> {
    let p = slice.plane;
    if p.rows == 0 || p.columns == 0 || p.rows > u16::MAX as usize || p.columns > u16::MAX as usize
    {
        return Err(EncodeError::Size {
            rows: p.rows,
            columns: p.columns,
        });
    }
    if slice.pixels.len() != p.rows * p.columns {
        return Err(EncodeError::PixelCount {
            len: slice.pixels.len(),
            rows: p.rows,
            columns: p.columns,
        });
    }
    let take = source.map_or(1, |s| s.take);
    let sop_instance_uid = instance_uid_of_take(series, slice.layer, take);
    let mut object = slice_object(study, series, slice, &sop_instance_uid);
    if let Some(source) = source {
        put(
            &mut object,
            tags::IMAGE_COMMENTS,
            VR::LT,
            source.comments().as_str(),
        );
    }
    let meta = FileMetaTableBuilder::new()
        .media_storage_sop_class_uid(CT_IMAGE_STORAGE)
        .media_storage_sop_instance_uid(sop_instance_uid.as_str())
        .transfer_syntax(EXPLICIT_VR_LE)
        .implementation_class_uid(IMPLEMENTATION_CLASS_UID)
        .implementation_version_name(concat!("LAYERWISE_", env!("CARGO_PKG_VERSION")));
    let mut file = object
        .with_meta(meta)
        .map_err(|e| EncodeError::encoder("file meta")(Box::new(e)))?;
    match compression {
        Compression::None => {}
        Compression::Deflate => {
            // dicom-rs streams the data set through its deflater in tiny writes (seconds for a
            // 4400 x 4400 slice); encode it plainly, then deflate it in parallel blocks.
            file.meta_mut().set_transfer_syntax(
                &dicom_transfer_syntax_registry::entries::DEFLATED_EXPLICIT_VR_LITTLE_ENDIAN,
            );
            let mut out = vec![0u8; 128];
            out.extend_from_slice(b"DICM");
            file.meta()
                .write(&mut out)
                .map_err(|e| EncodeError::encoder("file meta")(Box::new(e)))?;
            let mut plain = Vec::with_capacity(2 * slice.pixels.len() + 4096);
            file.write_dataset_with_ts(
                &mut plain,
                &dicom_transfer_syntax_registry::entries::EXPLICIT_VR_LITTLE_ENDIAN.erased(),
            )
            .map_err(|e| EncodeError::encoder("data set")(Box::new(e)))?;
            out.extend_from_slice(&deflate_parallel(&plain));
            // PS3.5 A.5: an odd-length deflated bitstream gets one trailing NUL (archives such
            // as Orthanc refuse the odd one over C-STORE). The preamble and meta group are even.
            if out.len() % 2 == 1 {
                out.push(0);
            }
            return Ok(out);
        }
        Compression::JpegLs => {
            if cfg!(not(feature = "jpegls")) {
                return Err(EncodeError::NoJpegLs);
            }
            let ts = dicom_transfer_syntax_registry::TransferSyntaxRegistry
                .get(JPEG_LS_LOSSLESS)
                .ok_or(EncodeError::NoJpegLs)?;
            file.transcode(ts)
                .map_err(|e| EncodeError::encoder("JPEG-LS encoding")(Box::new(e)))?;
            // The encoder adds attributes the (single-frame) CT Image IOD does not have.
            file.remove_element(tags::NUMBER_OF_FRAMES);
            file.remove_element(Tag(0x7FE0, 0x0003));
        }
    }
    let mut bytes = Vec::new();
    file.write_all(&mut bytes)
        .map_err(|e| EncodeError::encoder("data set")(Box::new(e)))?;
    Ok(bytes)
}

/// Raw deflate (RFC 1951, as DICOM's deflated transfer syntax wants) of `data`, compressed in
/// independent blocks on all cores: each block ends on a byte boundary with a sync flush, so
/// their concatenation is one valid stream (as pigz does); the last block finishes it.
pub fn deflate_parallel(data: &[u8]) -> Vec<u8> {
    use flate2::{Compress, Compression as Level, FlushCompress};
    use rayon::prelude::*;
    const BLOCK: usize = 1 << 21;
    let blocks: Vec<&[u8]> = if data.is_empty() {
        vec![data]
    } else {
        data.chunks(BLOCK).collect()
    };
    let last = blocks.len() - 1;
    let parts: Vec<Vec<u8>> = blocks
        .par_iter()
        .enumerate()
        .map(|(i, block)| {
            let mut compress = Compress::new(Level::fast(), false);
            let mut out = Vec::with_capacity(block.len() / 2 + 1024);
            let flush = if i == last {
                FlushCompress::Finish
            } else {
                FlushCompress::Sync
            };
            loop {
                let consumed = compress.total_in() as usize;
                if out.capacity() - out.len() < 1024 {
                    out.reserve(block.len() / 4 + 1024);
                }
                let status = compress.compress_vec(&block[consumed..], &mut out, flush);
                let done = compress.total_in() as usize == block.len();
                match status {
                    Ok(flate2::Status::StreamEnd) => break,
                    Ok(_) if done && i != last && out.capacity() > out.len() => break,
                    Ok(_) => {}
                    Err(_) => break,
                }
            }
            out
        })
        .collect();
    parts.concat()
}

/// Writes one slice atomically to `path`.
pub fn write_slice(
    path: &Path,
    study: &Study,
    series: &Series,
    slice: &Slice,
    compression: Compression,
) -> Result<(), DicomError> {
    write_slice_from(path, study, series, slice, compression, None)
}

/// [`write_slice`] of a slice made from a stored original ([`SliceSource`]); replaces the file
/// atomically.
pub fn write_slice_from(
    path: &Path,
    study: &Study,
    series: &Series,
    slice: &Slice,
    compression: Compression,
    source: Option<SliceSource>,
) -> Result<(), DicomError> {
    let bytes = encode_slice_from(study, series, slice, compression, source).map_err(|source| {
        DicomError::Encode {
            path: path.to_path_buf(),
            source,
        }
    })?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| crate::fsutil::WriteError {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    Ok(write_atomic(path, &bytes, true)?)
}

/// The take of the original a slice file was made from (its ImageComments, [`SliceSource`]):
/// `None` when there is no readable file; a slice written without the comment is take 1.
pub fn slice_take(path: &Path) -> Option<u32> {
    if !path.is_file() {
        return None;
    }
    check_lengths(path).ok()?;
    let obj = OpenFileOptions::new()
        .read_until(tags::PIXEL_DATA)
        .open_file(path)
        .ok()?;
    let Some(comments) = text(&obj, tags::IMAGE_COMMENTS) else {
        return Some(1);
    };
    comments
        .strip_prefix("take ")?
        .split(' ')
        .next()?
        .parse()
        .ok()
}

/// The SOP Instance UID a DICOM file's meta header names (None when it cannot be read).
pub fn file_instance_uid(path: &Path) -> Option<String> {
    check_lengths(path).ok()?;
    let obj = OpenFileOptions::new()
        .read_until(tags::SOP_CLASS_UID)
        .open_file(path)
        .ok()?;
    // As the push reads it (pacs::Instance), so the two compare equal.
    Some(obj.meta().media_storage_sop_instance_uid().to_string())
}

/// What `layerwise dicom info` reports of one series.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SeriesSummary {
    pub series_instance_uid: String,
    pub number: String,
    pub description: String,
    pub study_instance_uid: String,
    pub frame_of_reference_uid: String,
    pub files: Vec<PathBuf>,
    pub slices: usize,
    pub rows: u32,
    pub columns: u32,
    pub pixel_spacing_mm: [f64; 2],
    pub orientation: [f64; 6],
    pub first_position: [f64; 3],
    pub z_min: f64,
    pub z_max: f64,
    pub transfer_syntax: String,
    pub instance_numbers: (i64, i64),
}

fn text(obj: &InMemDicomObject, tag: Tag) -> Option<String> {
    obj.element(tag)
        .ok()?
        .to_str()
        .ok()
        .map(|s| s.trim().trim_end_matches('\0').to_string())
}

fn floats(obj: &InMemDicomObject, tag: Tag) -> Vec<f64> {
    text(obj, tag)
        .map(|s| {
            s.split('\\')
                .filter_map(|v| v.trim().parse().ok())
                .collect()
        })
        .unwrap_or_default()
}

/// Reads the headers (not the pixels) of every `.dcm` below `dir` and groups them by series.
pub fn series_info(dir: &Path) -> Result<Vec<SeriesSummary>, DicomError> {
    let mut files = Vec::new();
    collect_dcm(dir, &mut files, 0).map_err(|source| DicomError::Folder {
        path: dir.to_path_buf(),
        source,
    })?;
    files.sort();
    let mut series: BTreeMap<String, SeriesSummary> = BTreeMap::new();
    for path in files {
        check_lengths(&path)?;
        let obj = OpenFileOptions::new()
            .read_until(tags::PIXEL_DATA)
            .open_file(&path)
            .map_err(|e| DicomError::Read {
                path: path.clone(),
                message: e.to_string(),
            })?;
        let uid = text(&obj, tags::SERIES_INSTANCE_UID).unwrap_or_default();
        let position = floats(&obj, tags::IMAGE_POSITION_PATIENT);
        let [x, y, z] =
            <[f64; 3]>::try_from(position.as_slice()).map_err(|_| DicomError::Geometry {
                path: path.clone(),
                message: "no ImagePositionPatient with 3 values".into(),
            })?;
        let instance: i64 = text(&obj, tags::INSTANCE_NUMBER)
            .and_then(|s| s.parse().ok())
            .unwrap_or(0);
        let entry = series.entry(uid.clone()).or_insert_with(|| SeriesSummary {
            series_instance_uid: uid,
            number: text(&obj, tags::SERIES_NUMBER).unwrap_or_default(),
            description: text(&obj, tags::SERIES_DESCRIPTION).unwrap_or_default(),
            study_instance_uid: text(&obj, tags::STUDY_INSTANCE_UID).unwrap_or_default(),
            frame_of_reference_uid: text(&obj, tags::FRAME_OF_REFERENCE_UID).unwrap_or_default(),
            files: Vec::new(),
            slices: 0,
            rows: obj
                .element(tags::ROWS)
                .ok()
                .and_then(|e| e.to_int::<u32>().ok())
                .unwrap_or(0),
            columns: obj
                .element(tags::COLUMNS)
                .ok()
                .and_then(|e| e.to_int::<u32>().ok())
                .unwrap_or(0),
            pixel_spacing_mm: <[f64; 2]>::try_from(floats(&obj, tags::PIXEL_SPACING).as_slice())
                .unwrap_or([0.0; 2]),
            orientation: <[f64; 6]>::try_from(
                floats(&obj, tags::IMAGE_ORIENTATION_PATIENT).as_slice(),
            )
            .unwrap_or([0.0; 6]),
            first_position: [x, y, z],
            z_min: z,
            z_max: z,
            transfer_syntax: obj
                .meta()
                .transfer_syntax()
                .trim_end_matches('\0')
                .to_string(),
            instance_numbers: (instance, instance),
        });
        entry.files.push(path);
        entry.slices += 1;
        entry.z_min = entry.z_min.min(z);
        entry.z_max = entry.z_max.max(z);
        entry.instance_numbers = (
            entry.instance_numbers.0.min(instance),
            entry.instance_numbers.1.max(instance),
        );
    }
    let mut out: Vec<SeriesSummary> = series.into_values().collect();
    out.sort_by(|a, b| {
        a.number
            .parse::<i64>()
            .unwrap_or(0)
            .cmp(&b.number.parse::<i64>().unwrap_or(0))
    });
    Ok(out)
}

/// The `.dcm` files below `dir`: real folders only (a symbolic link to a folder is not followed,
/// so a link loop cannot make the search endless), at most 32 levels deep, each file once (a
/// link to a file already listed is not counted again).
fn collect_dcm(dir: &Path, out: &mut Vec<PathBuf>, depth: usize) -> std::io::Result<()> {
    let mut seen = std::collections::HashSet::new();
    collect_dcm_once(dir, out, depth, &mut seen)
}

fn collect_dcm_once(
    dir: &Path,
    out: &mut Vec<PathBuf>,
    depth: usize,
    seen: &mut std::collections::HashSet<(u64, u64)>,
) -> std::io::Result<()> {
    use std::os::unix::fs::MetadataExt;
    if depth > 32 {
        return Err(std::io::Error::other(format!(
            "{} is more than 32 folders deep",
            dir.display()
        )));
    }
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        if entry.file_type()?.is_dir() {
            collect_dcm_once(&path, out, depth + 1, seen)?;
        } else if path.extension().is_some_and(|e| e == "dcm") {
            // A dangling link is listed (and named when it cannot be read).
            let id = std::fs::metadata(&path).map(|m| (m.dev(), m.ino())).ok();
            if id.is_none_or(|id| seen.insert(id)) {
                out.push(path);
            }
        }
    }
    Ok(())
}

impl std::fmt::Display for SeriesSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "series {} {:<12} {} slices, {} x {} px at {} x {} mm, z {} … {} mm, instances {} … {}",
            self.number,
            self.description,
            self.slices,
            self.columns,
            self.rows,
            self.pixel_spacing_mm[0],
            self.pixel_spacing_mm[1],
            self.z_min,
            self.z_max,
            self.instance_numbers.0,
            self.instance_numbers.1
        )?;
        writeln!(
            f,
            "  first pixel at ({}, {}, {}) mm, orientation {:?}, transfer syntax {}",
            self.first_position[0],
            self.first_position[1],
            self.first_position[2],
            self.orientation,
            self.transfer_syntax
        )?;
        writeln!(
            f,
            "  study {}  frame of reference {}",
            self.study_instance_uid, self.frame_of_reference_uid
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derived_uids_are_stable_valid_and_distinct() {
        let a = derived_uid("2.25.1", "post_top");
        assert_eq!(a, derived_uid("2.25.1", "post_top"));
        assert_ne!(a, derived_uid("2.25.1", "pre_top"));
        assert!(a.len() <= 64 && a.starts_with("2.25.") && !a[5..].starts_with('0'));
        assert!(a[5..].chars().all(|c| c.is_ascii_digit()));
    }

    #[test]
    fn parallel_deflate_is_one_valid_raw_stream() {
        use std::io::Read;
        let data: Vec<u8> = (0..5_000_000u32)
            .map(|i| ((i * 31) % 251) as u8 ^ (i >> 13) as u8)
            .collect();
        for input in [&data[..], &data[..10], &[][..]] {
            let packed = deflate_parallel(input);
            let mut unpacked = Vec::new();
            flate2::read::DeflateDecoder::new(&packed[..])
                .read_to_end(&mut unpacked)
                .unwrap();
            assert_eq!(unpacked, input);
        }
    }

    /// Deflated files are whole even-length streams (one NUL pads an odd bitstream) and read back.
    #[test]
    fn deflated_files_have_even_length_and_read_back() {
        let study = Study {
            study_instance_uid: "2.25.1".into(),
            frame_of_reference_uid: "2.25.2".into(),
            date: "20261201".into(),
            time: "120000".into(),
            patient_name: "t^".into(),
            patient_id: "t".into(),
            study_id: "1".into(),
            description: "t".into(),
        };
        let series = Series::named(&study, 1, "post_top");
        let mut odd_before_pad = 0;
        for k in 0..12u16 {
            let pixels: Vec<u16> = (0..(40 + k as usize) * 37)
                .map(|i| ((i as u16).wrapping_mul(31 + k)) % 997)
                .collect();
            let slice = Slice {
                layer: u32::from(k) + 1,
                plane: Plane {
                    origin: [0.0, 0.0, 0.03],
                    pixel_mm: 0.5,
                    rows: 40 + k as usize,
                    columns: 37,
                    thickness_mm: 0.03,
                },
                pixels: &pixels,
                acquired: None,
                window: (500.0, 1000.0),
                derivation: "test",
            };
            let bytes = encode_slice(&study, &series, &slice, Compression::Deflate).unwrap();
            assert_eq!(bytes.len() % 2, 0, "slice {k}");
            odd_before_pad += usize::from(bytes.last() == Some(&0));
            let obj = dicom_object::from_reader(&bytes[128..]).unwrap();
            assert_eq!(
                obj.element(tags::ROWS).unwrap().to_int::<u16>().unwrap(),
                40 + k
            );
        }
        // Some of the twelve streams were odd: the padding was exercised.
        assert!(odd_before_pad > 0);
    }

    #[test]
    fn decimal_strings_fit_sixteen_characters() {
        assert_eq!(format_ds(0.0625), "0.0625");
        assert_eq!(format_ds(-137.46875), "-137.46875");
        assert_eq!(format_ds(-0.0), "0");
        assert!(format_ds(1.0 / 3.0).len() <= 16);
        assert!(format_ds(-123456.123456789).len() <= 16);
    }
}
