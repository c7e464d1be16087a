//! The CT Image IOD of one slice: the study, series and plane a slice belongs to, and the data
//! set (attributes and pixels) written for it, with its SOP instance UID.

use dicom_core::value::{PrimitiveValue, C};
use dicom_core::{DataElement, Tag, VR};
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;

use super::deflate::Samples;
use super::uid::derived_uid;
use super::CT_IMAGE_STORAGE;

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
    pub pixels: Samples<'a>,
    /// When the frame was taken (AcquisitionDate/Time, ContentDate/Time).
    pub acquired: Option<chrono::DateTime<chrono::Utc>>,
    /// Window for viewers: center and width.
    pub window: (f64, f64),
    /// How the pixels were made (DerivationDescription).
    pub derivation: &'a str,
}

pub(super) fn put(obj: &mut InMemDicomObject, tag: Tag, vr: VR, value: impl Into<PrimitiveValue>) {
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

/// Builds the CT Image data set of one slice, all but its pixel data (the last element).
pub(super) fn slice_object(
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
    o
}

/// The slice's PixelData element (OW), for the encoders that want it inside the data set
/// (JPEG-LS); the others write the samples straight after the data set (`encode.rs`).
pub(super) fn put_pixel_data(o: &mut InMemDicomObject, slice: &Slice) {
    let mut pixels = Vec::with_capacity(slice.pixels.len());
    match slice.pixels {
        Samples::Gray8(s) => pixels.extend(s.iter().map(|&v| u16::from(v))),
        Samples::Gray16(s) => pixels.extend_from_slice(s),
    }
    o.put(DataElement::new(
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::U16(C::from_vec(pixels)),
    ));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimal_strings_fit_sixteen_characters() {
        assert_eq!(format_ds(0.0625), "0.0625");
        assert_eq!(format_ds(-137.46875), "-137.46875");
        assert_eq!(format_ds(-0.0), "0");
        assert!(format_ds(1.0 / 3.0).len() <= 16);
        assert!(format_ds(-123456.123456789).len() <= 16);
    }
}
