//! Encoding a slice as a DICOM Part-10 file (transfer syntax, pixel data compression) and
//! writing it.

use std::path::Path;
use std::time::Instant;

use dicom_core::{Tag, VR};
use dicom_dictionary_std::tags;
use dicom_object::FileMetaTableBuilder;
use dicom_pixeldata::Transcode;
use dicom_transfer_syntax_registry::TransferSyntaxIndex;

use super::deflate::{deflate_samples_each, Samples};
use super::error::{DicomError, EncodeError};
use super::iod::{
    instance_uid_of_take, put, put_pixel_data, slice_object, Series, Slice, SliceSource, Study,
};
use super::{CT_IMAGE_STORAGE, IMPLEMENTATION_CLASS_UID};
use crate::clock::ms_since;
use crate::fsutil::{write_pending_with, Pending};

const EXPLICIT_VR_LE: &str = "1.2.840.10008.1.2.1";
const JPEG_LS_LOSSLESS: &str = "1.2.840.10008.1.2.4.80";

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
    let encoded = EncodedSlice::new(study, series, slice, compression, source)?;
    let mut out = Vec::with_capacity(encoded.capacity_hint());
    // Writing to a vector cannot fail.
    encoded
        .write_to(&mut out, &mut 0.0)
        .map_err(|e| EncodeError::encoder("cannot write the data set")(Box::new(e)))?;
    Ok(out)
}

/// A slice file in the parts it is written from, so that the samples are never copied into
/// one big buffer first: the file's opening (preamble, meta group and the data set up to the
/// pixel data's element header, deflated for [`Compression::Deflate`]), then the samples (as
/// they are, little endian, or deflated in parallel segments as they are written), then any
/// padding.
struct EncodedSlice<'a> {
    head: Vec<u8>,
    body: Body<'a>,
}

enum Body<'a> {
    /// The samples as 16-bit little-endian values.
    Plain(Samples<'a>),
    /// The samples, to be deflated as the rest of the stream the head opens; one NUL follows an
    /// odd-length stream (PS3.5 A.5).
    Deflate(Samples<'a>),
    /// Already part of the head (JPEG-LS encapsulates its pixel data in the data set).
    None,
}

/// The file meta group of a slice (explicit VR little endian until a compression says otherwise).
fn file_meta(sop_instance_uid: &str) -> FileMetaTableBuilder {
    FileMetaTableBuilder::new()
        .media_storage_sop_class_uid(CT_IMAGE_STORAGE)
        .media_storage_sop_instance_uid(sop_instance_uid)
        .transfer_syntax(EXPLICIT_VR_LE)
        .implementation_class_uid(IMPLEMENTATION_CLASS_UID)
        .implementation_version_name(concat!("LAYERWISE_", env!("CARGO_PKG_VERSION")))
}

/// The PixelData element's header (explicit VR little endian, OW, defined length).
fn pixel_data_header(samples: usize) -> Result<[u8; 12], EncodeError> {
    let bytes = u32::try_from(2 * samples).map_err(|_| EncodeError::PixelCount {
        len: samples,
        rows: 0,
        columns: 0,
    })?;
    let mut h = [0u8; 12];
    h[..4].copy_from_slice(&[0xE0, 0x7F, 0x10, 0x00]);
    h[4..6].copy_from_slice(b"OW");
    h[8..].copy_from_slice(&bytes.to_le_bytes());
    Ok(h)
}

impl<'a> EncodedSlice<'a> {
    fn new(
        study: &Study,
        series: &Series,
        slice: &Slice<'a>,
        compression: Compression,
        source: Option<SliceSource>,
    ) -> Result<EncodedSlice<'a>, EncodeError> {
        let p = slice.plane;
        if p.rows == 0
            || p.columns == 0
            || p.rows > u16::MAX as usize
            || p.columns > u16::MAX as usize
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
        if compression == Compression::JpegLs {
            put_pixel_data(&mut object, slice);
        }
        let mut file = object
            .with_meta(file_meta(&sop_instance_uid))
            .map_err(|e| EncodeError::encoder("cannot build the file meta group")(Box::new(e)))?;
        let write_error = |e| EncodeError::encoder("cannot write the data set")(Box::new(e));
        let mut head = vec![0u8; 128];
        head.extend_from_slice(b"DICM");
        match compression {
            Compression::None => {
                file.meta().write(&mut head).map_err(|e| {
                    EncodeError::encoder("cannot write the file meta group")(Box::new(e))
                })?;
                file.write_dataset_with_ts(
                    &mut head,
                    &dicom_transfer_syntax_registry::entries::EXPLICIT_VR_LITTLE_ENDIAN.erased(),
                )
                .map_err(write_error)?;
                head.extend_from_slice(&pixel_data_header(slice.pixels.len())?);
                Ok(EncodedSlice {
                    head,
                    body: Body::Plain(slice.pixels),
                })
            }
            Compression::Deflate => {
                // The data set up to the samples, deflated and flushed to a byte boundary; the
                // samples follow as the rest of the one deflate stream (`deflate/`).
                file.meta_mut().set_transfer_syntax(
                    &dicom_transfer_syntax_registry::entries::DEFLATED_EXPLICIT_VR_LITTLE_ENDIAN,
                );
                file.meta().write(&mut head).map_err(|e| {
                    EncodeError::encoder("cannot write the file meta group")(Box::new(e))
                })?;
                let mut plain = Vec::with_capacity(4096);
                file.write_dataset_with_ts(
                    &mut plain,
                    &dicom_transfer_syntax_registry::entries::EXPLICIT_VR_LITTLE_ENDIAN.erased(),
                )
                .map_err(write_error)?;
                plain.extend_from_slice(&pixel_data_header(slice.pixels.len())?);
                head.extend_from_slice(&deflate_flushed(&plain));
                Ok(EncodedSlice {
                    head,
                    body: Body::Deflate(slice.pixels),
                })
            }
            Compression::JpegLs => {
                if cfg!(not(feature = "jpegls")) {
                    return Err(EncodeError::NoJpegLs);
                }
                let ts = dicom_transfer_syntax_registry::TransferSyntaxRegistry
                    .get(JPEG_LS_LOSSLESS)
                    .ok_or(EncodeError::NoJpegLs)?;
                file.transcode(ts)
                    .map_err(|e| EncodeError::encoder("JPEG-LS encoding failed")(Box::new(e)))?;
                // The encoder adds attributes the (single-frame) CT Image IOD does not have.
                file.remove_element(tags::NUMBER_OF_FRAMES);
                file.remove_element(Tag(0x7FE0, 0x0003));
                let mut bytes = Vec::new();
                file.write_all(&mut bytes).map_err(write_error)?;
                Ok(EncodedSlice {
                    head: bytes,
                    body: Body::None,
                })
            }
        }
    }

    /// About the file's length in bytes (exact but for deflate, where it is the samples' count:
    /// a rectified frame's deflated samples take about a byte each).
    fn capacity_hint(&self) -> usize {
        let body = match &self.body {
            Body::Plain(s) => 2 * s.len(),
            Body::Deflate(s) => s.len(),
            Body::None => 0,
        };
        self.head.len() + body + 1
    }

    /// Writes the file's bytes in order; plain samples go out a block at a time, deflated ones
    /// a few segments at a time as they are coded (the system writes each back while the next
    /// are coded). Adds the time spent coding to `encode_ms`.
    fn write_to(&self, w: &mut impl std::io::Write, encode_ms: &mut f64) -> std::io::Result<()> {
        w.write_all(&self.head)?;
        match &self.body {
            Body::Plain(samples) => {
                const BLOCK: usize = 1 << 16;
                let mut buf = Vec::with_capacity(2 * BLOCK);
                for start in (0..samples.len()).step_by(BLOCK) {
                    buf.clear();
                    samples.extend_le(start..(start + BLOCK).min(samples.len()), &mut buf);
                    w.write_all(&buf)?;
                }
            }
            Body::Deflate(samples) => {
                // Two segments a core: each group keeps the cores busy, the system writes each
                // back while the next is coded, and only a group of the coded slice is held
                // (the whole of it on 10 cores or more: 19 segments for 4400 x 4400).
                let group = 2 * rayon::current_num_threads().max(1);
                let mut len = self.head.len();
                let mut started = Instant::now();
                deflate_samples_each(*samples, group, |parts| {
                    *encode_ms += ms_since(started);
                    for part in &parts {
                        w.write_all(part)?;
                        len += part.len();
                    }
                    started = Instant::now();
                    Ok::<(), std::io::Error>(())
                })?;
                if len % 2 == 1 {
                    w.write_all(&[0])?;
                }
            }
            Body::None => {}
        }
        Ok(())
    }
}

/// Raw deflate of `data`, ended with a sync flush (byte-aligned, not final), so that more of
/// the stream can follow.
fn deflate_flushed(data: &[u8]) -> Vec<u8> {
    use flate2::{Compress, Compression as Level, FlushCompress};
    let mut compress = Compress::new(Level::fast(), false);
    let mut out = Vec::with_capacity(data.len() / 2 + 1024);
    loop {
        let consumed = compress.total_in() as usize;
        if out.capacity() - out.len() < 1024 {
            out.reserve(data.len() / 4 + 1024);
        }
        let status = compress.compress_vec(&data[consumed..], &mut out, FlushCompress::Sync);
        let done = compress.total_in() as usize == data.len();
        match status {
            // The flush is complete once all input is taken and the output did not fill up.
            Ok(_) if done && out.capacity() > out.len() => break,
            Ok(_) => {}
            Err(_) => break,
        }
    }
    out
}

/// Writes one slice atomically to `path`.
pub fn write_slice(
    path: &Path,
    study: &Study,
    series: &Series,
    slice: &Slice,
    compression: Compression,
) -> Result<(), DicomError> {
    let (_, pending) = write_slice_pending(path, study, series, slice, compression, None)?;
    Ok(pending.commit()?)
}

/// How long a slice took to write, ms: encoding it (the data set, and the deflate of its samples,
/// which runs a group of segments at a time between the file's writes), and writing the file
/// (the time of that deflate left out; its commit, the fsync and rename, is timed by the caller).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WriteTimes {
    pub encode_ms: f64,
    pub write_ms: f64,
}

/// [`write_slice`] of a slice made from a stored original ([`SliceSource`]) up to its commit:
/// the slice written beside its place, not yet fsynced nor renamed over the slice before
/// ([`Pending::commit`] does both, on another thread if the caller has other work). The samples
/// go to the file as they are encoded, never as one more copy of the slice in memory. Tells how
/// long encoding and writing took (the commit left out).
pub fn write_slice_pending(
    path: &Path,
    study: &Study,
    series: &Series,
    slice: &Slice,
    compression: Compression,
    source: Option<SliceSource>,
) -> Result<(WriteTimes, Pending), DicomError> {
    let started = Instant::now();
    let encoded =
        EncodedSlice::new(study, series, slice, compression, source).map_err(|source| {
            DicomError::Encode {
                path: path.to_path_buf(),
                source,
            }
        })?;
    let mut encode_ms = ms_since(started);
    let started = Instant::now();
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| crate::fsutil::WriteError {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    // Straight to the file: the parts are large (plain samples go in 128 KiB blocks, deflated
    // ones in segments of about 1 MB), and a buffer would only copy them once more.
    let mut coding_ms = 0.0;
    let pending = write_pending_with(path, true, |file| encoded.write_to(file, &mut coding_ms))?;
    encode_ms += coding_ms;
    let times = WriteTimes {
        encode_ms,
        write_ms: (ms_since(started) - coding_ms).max(0.0),
    };
    Ok((times, pending))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dicom::Plane;

    fn study() -> Study {
        Study {
            study_instance_uid: "2.25.1".into(),
            frame_of_reference_uid: "2.25.2".into(),
            date: "20261201".into(),
            time: "120000".into(),
            patient_name: "t^".into(),
            patient_id: "t".into(),
            study_id: "1".into(),
            description: "t".into(),
        }
    }

    /// The file as dicom-rs writes the whole object, pixel data inside (how every slice was
    /// written before the samples were streamed): the streamed files must be the same bytes
    /// (explicit VR) or inflate to the same data set (deflate).
    #[test]
    fn streamed_slices_are_the_bytes_dicom_rs_writes() {
        use std::io::Read;
        let study = study();
        let series = Series::named(&study, 3, "post_side");
        let (rows, columns) = (301, 257);
        let gray8: Vec<u8> = (0..rows * columns)
            .map(|i| {
                if i % 97 < 20 {
                    0
                } else {
                    ((i * 7) % 251) as u8
                }
            })
            .collect();
        let gray16: Vec<u16> = (0..rows * columns)
            .map(|i| (i as u16).wrapping_mul(2654))
            .collect();
        for samples in [Samples::Gray8(&gray8), Samples::Gray16(&gray16)] {
            let slice = Slice {
                layer: 12,
                plane: Plane {
                    origin: [-1.5, 2.25, 0.36],
                    pixel_mm: 0.5,
                    rows,
                    columns,
                    thickness_mm: 0.03,
                },
                pixels: samples,
                acquired: None,
                window: (128.0, 256.0),
                derivation: "test",
            };
            let source = SliceSource {
                take: 2,
                file: "raw/L00012_post_side.jpg",
            };
            let uid = instance_uid_of_take(&series, 12, 2);
            let mut object = slice_object(&study, &series, &slice, &uid);
            put(
                &mut object,
                tags::IMAGE_COMMENTS,
                VR::LT,
                source.comments().as_str(),
            );
            put_pixel_data(&mut object, &slice);
            let file = object.with_meta(file_meta(&uid)).unwrap();
            let mut reference = Vec::new();
            file.write_all(&mut reference).unwrap();
            let plain = encode_slice_from(&study, &series, &slice, Compression::None, Some(source))
                .unwrap();
            assert!(plain == reference, "explicit VR file differs");
            // Deflated: the same data set after the meta group.
            let deflated =
                encode_slice_from(&study, &series, &slice, Compression::Deflate, Some(source))
                    .unwrap();
            let mut dataset_reference = Vec::new();
            file.write_dataset_with_ts(
                &mut dataset_reference,
                &dicom_transfer_syntax_registry::entries::EXPLICIT_VR_LITTLE_ENDIAN.erased(),
            )
            .unwrap();
            // Preamble, DICM, then the meta group: (0002,0000) UL (12 bytes) and its length.
            let group = u32::from_le_bytes(deflated[140..144].try_into().unwrap()) as usize;
            let meta_len = 144 + group;
            let mut inflated = Vec::new();
            flate2::read::DeflateDecoder::new(&deflated[meta_len..])
                .read_to_end(&mut inflated)
                .unwrap();
            assert!(inflated == dataset_reference, "deflated data set differs");
        }
    }

    /// Deflated files are whole even-length streams (one NUL pads an odd bitstream) and read back.
    #[test]
    fn deflated_files_have_even_length_and_read_back() {
        let study = study();
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
                pixels: (&pixels).into(),
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
}
