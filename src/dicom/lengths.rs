//! A walk over a DICOM file's element headers that refuses a stated length the file cannot hold,
//! before a parser sizes a read by it (dicom-rs allocates what an element claims: a 1 KB file
//! whose PixelData claims 0xFFFFFFF0 bytes cost 4 GB).

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use super::DicomError;

/// Value representations whose length is 16-bit in explicit VR. Every other VR, an unknown
/// one included (PS3.5 6.2.2, as dicom-rs reads it), has 2 reserved bytes and a 32-bit length.
const SHORT_VRS: [&[u8; 2]; 21] = [
    b"AE", b"AS", b"AT", b"CS", b"DA", b"DS", b"DT", b"FL", b"FD", b"IS", b"LO", b"LT", b"PN",
    b"SH", b"SL", b"SS", b"ST", b"TM", b"UI", b"UL", b"US",
];

const UNDEFINED: u32 = 0xFFFF_FFFF;

/// Bytes per value of a binary VR (1 for the others): dicom-rs reads `length / size` values, so
/// a length that is no multiple of it loses its place in the file, and the next header it reads
/// can claim gigabytes (found by mutation fuzzing).
fn value_size(vr: &[u8; 2]) -> u32 {
    match vr {
        b"US" | b"SS" | b"OW" => 2,
        b"UL" | b"SL" | b"FL" | b"AT" | b"OL" | b"OF" => 4,
        b"FD" | b"OD" | b"OV" | b"SV" | b"UV" => 8,
        _ => 1,
    }
}

/// How the data set after the file meta group is encoded.
#[derive(Clone, Copy)]
enum Encoding {
    Explicit {
        big_endian: bool,
    },
    Implicit,
    /// Deflated: the lengths are inside the compressed stream and are not walked. A deflated
    /// file of 835 bytes whose element claims gigabytes still makes dicom-rs reserve and fill
    /// them (found by mutation fuzzing; walking the inflated data set is still to do).
    Deflated,
}

/// Checks that every element of the DICOM Part-10 file at `path` fits in the file; `Ok(false)`
/// when the file is not Part-10 (no `DICM` at byte 128), `Ok(true)` when every length fits.
/// Undefined lengths (sequences, encapsulated pixel data) are walked into, so items and
/// fragments are checked too.
pub fn check_lengths(path: &Path) -> Result<bool, DicomError> {
    let damaged = |message: String| DicomError::Damaged {
        path: path.to_path_buf(),
        message,
    };
    let read_err = |source| DicomError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = crate::fsutil::open_regular(path).map_err(read_err)?;
    let size = file.metadata().map_err(read_err)?.len();
    let mut r = BufReader::with_capacity(8192, file);
    let mut preamble = [0u8; 132];
    if r.read_exact(&mut preamble).is_err() || &preamble[128..] != b"DICM" {
        return Ok(false);
    }
    let mut pos = 132u64;
    let mut encoding = Encoding::Explicit { big_endian: false };
    let mut in_meta = true;
    // Inside encapsulated pixel data, items are compressed fragments (skipped, not walked).
    let mut in_fragments = false;
    while pos < size {
        let mut head = [0u8; 8];
        if r.read_exact(&mut head).is_err() {
            // A few bytes after the last element (padding, or a cut header): no length to
            // trust; the parser judges them.
            return Ok(true);
        }
        let big = matches!(encoding, Encoding::Explicit { big_endian: true }) && !in_meta;
        let u16_at = |b: &[u8]| {
            if big {
                u16::from_be_bytes([b[0], b[1]])
            } else {
                u16::from_le_bytes([b[0], b[1]])
            }
        };
        let (group, element) = (u16_at(&head[0..2]), u16_at(&head[2..4]));
        if in_meta && group != 0x0002 {
            in_meta = false;
            if matches!(encoding, Encoding::Deflated) {
                return Ok(true);
            }
            if matches!(encoding, Encoding::Explicit { big_endian: true }) {
                // Re-read this header as big endian.
                r.seek(SeekFrom::Start(pos)).map_err(read_err)?;
                continue;
            }
        }
        let u32_of = |b: [u8; 4]| {
            if big {
                u32::from_be_bytes(b)
            } else {
                u32::from_le_bytes(b)
            }
        };
        let explicit = in_meta || matches!(encoding, Encoding::Explicit { .. });
        let mut sequence = false;
        let mut unit = 1;
        let (length, header) = if group == 0xFFFE {
            // Items and delimiters: tag and a 32-bit length in every encoding.
            (u32_of([head[4], head[5], head[6], head[7]]), 8)
        } else if explicit {
            let vr = [head[4], head[5]];
            sequence = &vr == b"SQ";
            unit = value_size(&vr);
            if !SHORT_VRS.contains(&&vr) {
                let mut len = [0u8; 4];
                if r.read_exact(&mut len).is_err() {
                    return Ok(true);
                }
                (u32_of(len), 12)
            } else {
                (u32::from(u16_at(&head[6..8])), 8)
            }
        } else {
            (u32_of([head[4], head[5], head[6], head[7]]), 8)
        };
        pos += header;
        if group == 0xFFFE && element == 0xE0DD {
            in_fragments = false;
        }
        if length == UNDEFINED {
            // A sequence, an item or encapsulated pixel data: walk into it.
            in_fragments |= (group, element) == (0x7FE0, 0x0010);
            continue;
        }
        if length % unit != 0 {
            return Err(damaged(format!(
                "element ({group:04X},{element:04X}) at byte {} is {length} bytes long, no \
                 multiple of its values' {unit} bytes: the file is damaged; export it again",
                pos - header
            )));
        }
        let left = size - pos.min(size);
        if u64::from(length) > left {
            return Err(damaged(format!(
                "element ({group:04X},{element:04X}) at byte {} claims {length} bytes but only \
                 {left} bytes follow in the {size}-byte file: the file is cut short or damaged; \
                 export it again",
                pos - header
            )));
        }
        if in_meta && (group, element) == (0x0002, 0x0010) {
            let mut uid = vec![0u8; length as usize];
            r.read_exact(&mut uid).map_err(read_err)?;
            let uid = String::from_utf8_lossy(&uid);
            encoding = match uid.trim_end_matches(['\0', ' ']) {
                "1.2.840.10008.1.2" => Encoding::Implicit,
                "1.2.840.10008.1.2.2" => Encoding::Explicit { big_endian: true },
                "1.2.840.10008.1.2.1.99" => Encoding::Deflated,
                _ => Encoding::Explicit { big_endian: false },
            };
            pos += u64::from(length);
        } else if sequence || (group == 0xFFFE && element == 0xE000 && !in_fragments) {
            // A sequence or an item of defined length: its elements are walked too.
        } else {
            r.seek_relative(i64::from(length)).map_err(read_err)?;
            pos += u64::from(length);
        }
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    // Files with lengths that fit and lengths that lie: tests/it/bounded_inputs.rs (through the
    // binary, with a sequence of undefined length holding an item of defined length).
    #[test]
    fn a_file_without_the_part10_magic_is_left_to_the_parser() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("x.dcm");
        std::fs::write(&path, b"not dicom").expect("write");
        assert!(!check_lengths(&path).expect("not part 10"));
        let mut short = vec![0u8; 128];
        short.extend(b"DICM\x02\x00");
        std::fs::write(&path, short).expect("write");
        // A cut header states no length: left to the parser too.
        assert!(check_lengths(&path).expect("cut header"));
    }

    #[test]
    fn a_binary_value_whose_length_is_no_multiple_of_its_size_is_refused() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("x.dcm");
        // The meta group's transfer syntax (explicit VR little endian), then one element.
        let file = |vr: &[u8; 2], len: u16| {
            let mut b = vec![0u8; 128];
            b.extend(b"DICM\x02\x00\x10\x00UI\x14\x001.2.840.10008.1.2.1\0");
            b.extend(b"\x28\x00\x10\x00");
            b.extend(vr);
            b.extend(len.to_le_bytes());
            b.extend(vec![0u8; usize::from(len)]);
            b
        };
        for (vr, len, refused) in [(b"US", 1, true), (b"US", 2, false), (b"FD", 12, true)] {
            std::fs::write(&path, file(vr, len)).expect("write");
            match check_lengths(&path) {
                Err(e) => assert!(refused && e.to_string().contains("no multiple"), "{e}"),
                Ok(fine) => assert!(!refused && fine, "{vr:?} {len}"),
            }
        }
    }
}
