//! Encoding a slice as a DICOM Part-10 file (transfer syntax, pixel data compression) and
//! writing it.

use std::path::Path;

use dicom_core::{Tag, VR};
use dicom_dictionary_std::tags;
use dicom_object::FileMetaTableBuilder;
use dicom_pixeldata::Transcode;
use dicom_transfer_syntax_registry::TransferSyntaxIndex;

use super::error::{DicomError, EncodeError};
use super::iod::{instance_uid_of_take, put, slice_object, Series, Slice, SliceSource, Study};
use super::{CT_IMAGE_STORAGE, IMPLEMENTATION_CLASS_UID};
use crate::fsutil::write_atomic;

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
        .map_err(|e| EncodeError::encoder("cannot build the file meta group")(Box::new(e)))?;
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
            file.meta().write(&mut out).map_err(|e| {
                EncodeError::encoder("cannot write the file meta group")(Box::new(e))
            })?;
            let mut plain = Vec::with_capacity(2 * slice.pixels.len() + 4096);
            file.write_dataset_with_ts(
                &mut plain,
                &dicom_transfer_syntax_registry::entries::EXPLICIT_VR_LITTLE_ENDIAN.erased(),
            )
            .map_err(|e| EncodeError::encoder("cannot write the data set")(Box::new(e)))?;
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
                .map_err(|e| EncodeError::encoder("JPEG-LS encoding failed")(Box::new(e)))?;
            // The encoder adds attributes the (single-frame) CT Image IOD does not have.
            file.remove_element(tags::NUMBER_OF_FRAMES);
            file.remove_element(Tag(0x7FE0, 0x0003));
        }
    }
    let mut bytes = Vec::new();
    file.write_all(&mut bytes)
        .map_err(|e| EncodeError::encoder("cannot write the data set")(Box::new(e)))?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dicom::Plane;

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
}
