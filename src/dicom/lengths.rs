//! A walk over a DICOM file's element headers that refuses a stated length the file cannot hold,
//! before a parser sizes a read by it (dicom-rs allocates what an element claims: a 1 KB file
//! whose PixelData claims 0xFFFFFFF0 bytes cost 4 GB).
//!
//! A deflated data set (PS3.5 A.5) is walked as it inflates: its lengths are checked against
//! what the stream holds, found by reading, since no size is stated for it.

use std::io::{self, BufReader, Read};
use std::path::Path;

use flate2::bufread::DeflateDecoder;

use super::DicomError;

/// Value representations whose length is 16-bit in explicit VR. Every other VR, an unknown
/// one included (PS3.5 6.2.2, as dicom-rs reads it), has 2 reserved bytes and a 32-bit length.
const SHORT_VRS: [&[u8; 2]; 21] = [
    b"AE", b"AS", b"AT", b"CS", b"DA", b"DS", b"DT", b"FL", b"FD", b"IS", b"LO", b"LT", b"PN",
    b"SH", b"SL", b"SS", b"ST", b"TM", b"UI", b"UL", b"US",
];

const UNDEFINED: u32 = 0xFFFF_FFFF;
const PIXEL_DATA: (u16, u16) = (0x7FE0, 0x0010);

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
    /// Explicit VR little endian, deflated (a raw deflate stream, no zlib header).
    Deflated,
}

/// Checks that every element of the DICOM Part-10 file at `path` fits in the file; `Ok(false)`
/// when the file is not Part-10 (no `DICM` at byte 128), `Ok(true)` when every length fits.
/// Undefined lengths (sequences, encapsulated pixel data) are walked into, so items and
/// fragments are checked too.
pub fn check_lengths(path: &Path) -> Result<bool, DicomError> {
    check_lengths_until(path, None)
}

/// [`check_lengths`] for a reader that stops before the top-level element `until` (dicom-rs's
/// `read_until`): a deflated data set is inflated only that far, since the parser reads no
/// further. A file that is not deflated is walked whole: skipping costs nothing there.
pub fn check_lengths_until(
    path: &Path,
    until: Option<dicom_core::Tag>,
) -> Result<bool, DicomError> {
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
    let mut walk = Walk {
        r,
        pos: 132,
        size: Some(size),
        big_endian: false,
        implicit: false,
        path,
        place: "",
    };
    let Some(encoding) = walk.meta()? else {
        return Ok(true);
    };
    match encoding {
        Encoding::Deflated => {
            // The meta group was read to its end: the reader is where the stream starts.
            let mut walk = Walk {
                r: DeflateDecoder::new(walk.r),
                pos: 0,
                size: None,
                big_endian: false,
                implicit: false,
                path,
                place: " of the inflated data set",
            };
            walk.data_set(until)?;
        }
        Encoding::Explicit { big_endian } => {
            walk.big_endian = big_endian;
            walk.data_set(None)?;
        }
        Encoding::Implicit => {
            walk.implicit = true;
            walk.data_set(None)?;
        }
    }
    Ok(true)
}

/// What the walk reads: the file, whose size bounds every length, or a deflated data set,
/// whose end is found by reading.
trait Source: Read {
    /// Skips `n` bytes; how many there were.
    fn skip(&mut self, n: u64) -> io::Result<u64>;
}

impl Source for BufReader<std::fs::File> {
    fn skip(&mut self, n: u64) -> io::Result<u64> {
        // Only called for lengths checked against the file's size.
        let n_signed = i64::try_from(n).map_err(|_| io::ErrorKind::InvalidInput)?;
        self.seek_relative(n_signed)?;
        Ok(n)
    }
}

impl<R: io::BufRead> Source for DeflateDecoder<R> {
    fn skip(&mut self, n: u64) -> io::Result<u64> {
        io::copy(&mut self.take(n), &mut io::sink())
    }
}

/// The walk's place in one stream of elements.
struct Walk<'p, R> {
    r: R,
    /// Bytes read so far: the offset in the file, or in the inflated data set.
    pos: u64,
    /// The file's size; `None` for an inflated data set.
    size: Option<u64>,
    big_endian: bool,
    implicit: bool,
    path: &'p Path,
    /// Where `pos` counts, for messages ("" in the file).
    place: &'static str,
}

/// One element's header as the walk reads it.
struct Header {
    group: u16,
    element: u16,
    vr: Option<[u8; 2]>,
    length: u32,
    /// Bytes of the header itself.
    bytes: u64,
}

impl<R: Source> Walk<'_, R> {
    fn damaged(&self, message: String) -> DicomError {
        DicomError::Damaged {
            path: self.path.to_path_buf(),
            message,
        }
    }

    /// A read error: in an inflated data set, the stream's own damage.
    fn read_error(&self, source: io::Error) -> DicomError {
        if self.size.is_none() {
            return self.damaged(format!(
                "the deflated data set cannot be inflated past byte {} ({source}): the file \
                 is damaged; export it again",
                self.pos
            ));
        }
        DicomError::Io {
            path: self.path.to_path_buf(),
            source,
        }
    }

    /// A header the stream ends inside (`None`), or a stream that cannot be inflated.
    fn cut(&self, e: io::Error) -> Result<Option<Header>, DicomError> {
        if e.kind() == io::ErrorKind::UnexpectedEof || self.size.is_some() {
            return Ok(None);
        }
        Err(self.read_error(e))
    }

    /// Reads the next header; `None` at the end, or on a cut header (no length to trust: the
    /// parser judges those bytes).
    fn header(&mut self, explicit: bool) -> Result<Option<Header>, DicomError> {
        let mut head = [0u8; 8];
        if let Err(e) = self.r.read_exact(&mut head) {
            return self.cut(e);
        }
        let big = self.big_endian;
        let u16_at = |b: &[u8]| {
            let b = [b[0], b[1]];
            if big {
                u16::from_be_bytes(b)
            } else {
                u16::from_le_bytes(b)
            }
        };
        let u32_of = |b: [u8; 4]| {
            if big {
                u32::from_be_bytes(b)
            } else {
                u32::from_le_bytes(b)
            }
        };
        let (group, element) = (u16_at(&head[0..2]), u16_at(&head[2..4]));
        let tail = [head[4], head[5], head[6], head[7]];
        let header = if group == 0xFFFE || !explicit {
            // Items and delimiters: tag and a 32-bit length in every encoding.
            Header {
                group,
                element,
                vr: None,
                length: u32_of(tail),
                bytes: 8,
            }
        } else {
            let vr = [head[4], head[5]];
            if SHORT_VRS.contains(&&vr) {
                Header {
                    group,
                    element,
                    vr: Some(vr),
                    length: u32::from(u16_at(&head[6..8])),
                    bytes: 8,
                }
            } else {
                let mut len = [0u8; 4];
                if let Err(e) = self.r.read_exact(&mut len) {
                    return self.cut(e);
                }
                Header {
                    group,
                    element,
                    vr: Some(vr),
                    length: u32_of(len),
                    bytes: 12,
                }
            }
        };
        self.pos += header.bytes;
        Ok(Some(header))
    }

    /// Refuses a defined length the file cannot hold, or one that is no multiple of its VR's
    /// value size.
    fn check(&self, h: &Header) -> Result<(), DicomError> {
        let (group, element, length) = (h.group, h.element, h.length);
        let at = self.pos - h.bytes;
        let unit = h.vr.as_ref().map_or(1, value_size);
        if length % unit != 0 {
            return Err(self.damaged(format!(
                "element ({group:04X},{element:04X}) at byte {at}{} is {length} bytes long, no \
                 multiple of its values' {unit} bytes: the file is damaged; export it again",
                self.place
            )));
        }
        if let Some(size) = self.size {
            let left = size - self.pos.min(size);
            if u64::from(length) > left {
                return Err(self.damaged(format!(
                    "element ({group:04X},{element:04X}) at byte {at} claims {length} bytes but \
                     only {left} bytes follow in the {size}-byte file: the file is cut short or \
                     damaged; export it again"
                )));
            }
        }
        Ok(())
    }

    /// Skips a checked value; in an inflated data set, refuses one the stream ends inside.
    fn skip(&mut self, h: &Header) -> Result<(), DicomError> {
        let length = u64::from(h.length);
        let there = self.r.skip(length).map_err(|e| self.read_error(e))?;
        self.pos += there;
        if there < length {
            return Err(self.damaged(format!(
                "element ({:04X},{:04X}) at byte {}{} claims {length} bytes but the data set \
                 ends {there} bytes after its header: the file is cut short or damaged; export \
                 it again",
                h.group,
                h.element,
                self.pos - there - h.bytes,
                self.place
            )));
        }
        Ok(())
    }

    /// Walks the data set's elements as dicom-rs's data set reader reads them (its states, so
    /// that the two never read the same bytes differently: mutation fuzzing found each place
    /// where they did). Sequences and items are walked into, fragments of encapsulated pixel
    /// data skipped; with `until`, the walk ends at the first top-level element at or past it.
    /// Where dicom-rs would stop with an error of its own, the walk ends too: the parser reads
    /// nothing past it.
    fn data_set(&mut self, until: Option<dicom_core::Tag>) -> Result<(), DicomError> {
        let mut open: Vec<Open> = Vec::new();
        // At a sequence's level, where only item headers and delimiters are read.
        let mut in_sequence = false;
        loop {
            // A container of defined length ends where its length says; past it dicom-rs stops.
            while let Some(&Open {
                end: Some(end),
                item,
                ..
            }) = open.last()
            {
                if self.pos < end {
                    break;
                }
                if self.pos > end {
                    return Ok(());
                }
                open.pop();
                in_sequence = item;
            }
            if in_sequence {
                // Tag and a 32-bit length, in every encoding.
                let Some(h) = self.header(false)? else {
                    return Ok(());
                };
                let pixel = open.last().is_some_and(|o| o.pixel);
                match (h.group, h.element, h.length) {
                    (0xFFFE, 0xE000, UNDEFINED) if pixel => return Ok(()),
                    (0xFFFE, 0xE000, _) if pixel => {
                        // A fragment (or the offset table): read whole.
                        self.check(&h)?;
                        self.skip(&h)?;
                    }
                    (0xFFFE, 0xE000, length) => {
                        let end = (length != UNDEFINED).then(|| self.pos + u64::from(length));
                        if end.is_some() {
                            self.check(&h)?;
                        }
                        open.push(Open {
                            item: true,
                            end,
                            pixel: false,
                        });
                        in_sequence = false;
                    }
                    // Delimiters: no value follows, whatever a sequence delimiter's length says.
                    (0xFFFE, 0xE00D, 0) | (0xFFFE, 0xE0DD, _) => {
                        open.pop();
                        in_sequence = h.element == 0xE00D;
                    }
                    // Anything else here (an item delimiter with a length too) dicom-rs refuses.
                    _ => return Ok(()),
                }
                continue;
            }
            let Some(mut h) = self.header(!self.implicit)? else {
                return Ok(());
            };
            let tag = (h.group, h.element);
            if self.implicit && h.group != 0xFFFE {
                h.vr = Some(implicit_vr(tag));
            }
            if tag == (0xFFFE, 0xE00D) {
                // An item's end: no value is read after it, whatever its length says; outside
                // any sequence it is passed over.
                if open.pop().is_some() {
                    in_sequence = true;
                }
                continue;
            }
            if open.is_empty() && until.is_some_and(|until| dicom_core::Tag(tag.0, tag.1) >= until)
            {
                return Ok(());
            }
            let sequence = h.vr == Some(*b"SQ");
            if sequence || h.length == UNDEFINED {
                // A sequence; an element of undefined length is read as one too, and pixel data
                // of undefined length is a sequence of fragments.
                let end = if h.length == UNDEFINED {
                    None
                } else {
                    self.check(&h)?;
                    Some(self.pos + u64::from(h.length))
                };
                open.push(Open {
                    item: false,
                    end,
                    pixel: !sequence && tag == PIXEL_DATA,
                });
                in_sequence = true;
                continue;
            }
            // A value, an item or a sequence delimiter met outside a sequence's level included:
            // dicom-rs reads those as values too.
            self.check(&h)?;
            self.skip(&h)?;
        }
    }
}

/// A sequence or an item the walk is in, as dicom-rs's reader keeps it.
struct Open {
    item: bool,
    /// Where it ends when its length is defined (a position as `Walk::pos` counts).
    end: Option<u64>,
    /// Encapsulated pixel data: its items are fragments, read whole.
    pixel: bool,
}

impl Walk<'_, BufReader<std::fs::File>> {
    /// Walks the file meta group (explicit VR little endian) and says how the data set after it
    /// is encoded; `None` where dicom-rs refuses the group (no group length first, an undefined
    /// length, the file ending inside it), so nothing after it is read. The group ends where its
    /// group length says, whatever the groups of the elements before that: dicom-rs reads them
    /// all as the meta group's (a fuzzed file whose meta elements changed group had the walk
    /// read its data set in another encoding than dicom-rs).
    fn meta(&mut self) -> Result<Option<Encoding>, DicomError> {
        let mut encoding = Encoding::Explicit { big_endian: false };
        let Some(h) = self.header(true)? else {
            return Ok(None);
        };
        if (h.group, h.element, h.length) != (0x0002, 0x0000, 4) {
            return Ok(None);
        }
        let mut value = [0u8; 4];
        if self.r.read_exact(&mut value).is_err() {
            return Ok(None);
        }
        self.pos += 4;
        let end = self.pos + u64::from(u32::from_le_bytes(value));
        while self.pos < end {
            let Some(h) = self.header(true)? else {
                return Ok(None);
            };
            if h.length == UNDEFINED {
                return Ok(None);
            }
            // dicom-rs reads the meta group's values as bytes: only the file's size bounds them.
            let h = Header { vr: None, ..h };
            self.check(&h)?;
            if (h.group, h.element) == (0x0002, 0x0010) {
                let mut uid = vec![0u8; h.length as usize];
                self.r
                    .read_exact(&mut uid)
                    .map_err(|e| self.read_error(e))?;
                self.pos += u64::from(h.length);
                encoding = match String::from_utf8_lossy(&uid).trim_end_matches(['\0', ' ']) {
                    "1.2.840.10008.1.2" => Encoding::Implicit,
                    "1.2.840.10008.1.2.2" => Encoding::Explicit { big_endian: true },
                    "1.2.840.10008.1.2.1.99" => Encoding::Deflated,
                    _ => Encoding::Explicit { big_endian: false },
                };
            } else {
                self.skip(&h)?;
            }
        }
        Ok(Some(encoding))
    }
}

/// The VR dicom-rs gives an element in implicit VR: OW for pixel and overlay data, the
/// dictionary's (its first when it names two), UN for a tag it does not know.
fn implicit_vr((group, element): (u16, u16)) -> [u8; 2] {
    use dicom_core::dictionary::DataDictionary;
    if (group, element) == PIXEL_DATA || (group >> 8 == 0x60 && element == 0x3000) {
        return *b"OW";
    }
    dicom_dictionary_std::StandardDataDictionary
        .by_tag(dicom_core::Tag(group, element))
        .map_or(*b"UN", |entry| {
            use dicom_core::dictionary::DataDictionaryEntry;
            entry.vr().relaxed().to_bytes()
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    const PIXEL_DATA_TAG: dicom_core::Tag = dicom_dictionary_std::tags::PIXEL_DATA;

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
            let mut ds = b"\x28\x00\x10\x00".to_vec();
            ds.extend(vr);
            ds.extend(len.to_le_bytes());
            ds.extend(vec![0u8; usize::from(len)]);
            part10(EXPLICIT, &ds)
        };
        for (vr, len, refused) in [(b"US", 1, true), (b"US", 2, false), (b"FD", 12, true)] {
            std::fs::write(&path, file(vr, len)).expect("write");
            match check_lengths(&path) {
                Err(e) => assert!(refused && e.to_string().contains("no multiple"), "{e}"),
                Ok(fine) => assert!(!refused && fine, "{vr:?} {len}"),
            }
        }
    }

    /// One explicit-VR little-endian element; `length` overrides the value's length (a lie).
    fn element(tag: (u16, u16), vr: &[u8; 2], value: &[u8], length: Option<u32>) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend(tag.0.to_le_bytes());
        out.extend(tag.1.to_le_bytes());
        out.extend(vr);
        let len = length.unwrap_or(value.len() as u32);
        if SHORT_VRS.contains(&vr) {
            out.extend((len as u16).to_le_bytes());
        } else {
            out.extend([0, 0]);
            out.extend(len.to_le_bytes());
        }
        out.extend(value);
        out
    }

    /// A Part-10 file of `data_set` in transfer syntax `ts`, deflated when `ts` says so.
    fn part10(ts: &str, data_set: &[u8]) -> Vec<u8> {
        use std::io::Write;
        let class = b"1.2.840.10008.5.1.4.1.1.7\0";
        let mut ts = ts.as_bytes().to_vec();
        if ts.len() % 2 == 1 {
            ts.push(0);
        }
        let mut meta = element((2, 1), b"OB", &[0, 1], None);
        meta.extend(element((2, 2), b"UI", class, None));
        meta.extend(element((2, 3), b"UI", b"1.2.3.4.5\0", None));
        meta.extend(element((2, 0x10), b"UI", &ts, None));
        let mut file = vec![0u8; 128];
        file.extend(b"DICM");
        let group_length = (meta.len() as u32).to_le_bytes();
        file.extend(element((2, 0), b"UL", &group_length, None));
        file.extend(meta);
        if ts.starts_with(b"1.2.840.10008.1.2.1.99") {
            let mut z = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::fast());
            z.write_all(data_set).expect("deflate");
            file.extend(z.finish().expect("deflate"));
        } else {
            file.extend(data_set);
        }
        file
    }

    const DEFLATED: &str = "1.2.840.10008.1.2.1.99";

    /// A secondary capture's elements: an icon sequence whose item holds pixel data of its
    /// own, a private OB of `private` bytes stated, then 4 x 4 pixels of `pixels` bytes stated.
    fn data_set(private: Option<u32>, pixels: Option<u32>) -> Vec<u8> {
        let mut ds = element((8, 0x16), b"UI", b"1.2.840.10008.5.1.4.1.1.7\0", None);
        ds.extend(element((8, 0x18), b"UI", b"1.2.3.4.5\0", None));
        let mut icon = element((0x28, 0x10), b"US", &1u16.to_le_bytes(), None);
        icon.extend(element((0x28, 0x11), b"US", &1u16.to_le_bytes(), None));
        icon.extend(element(PIXEL_DATA, b"OB", &[7, 0], None));
        let mut item = vec![0xFE, 0xFF, 0x00, 0xE0];
        item.extend((icon.len() as u32).to_le_bytes());
        item.extend(icon);
        ds.extend(element((0x88, 0x200), b"SQ", &item, None));
        ds.extend(element((0x99, 0x1000), b"OB", &[1, 2, 3, 4], private));
        ds.extend(element((0x28, 0x10), b"US", &4u16.to_le_bytes(), None));
        ds.extend(element((0x28, 0x11), b"US", &4u16.to_le_bytes(), None));
        ds.extend(element(PIXEL_DATA, b"OB", &[9; 16], pixels));
        ds
    }

    fn written(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, bytes).expect("write");
        path
    }

    #[test]
    fn a_deflated_data_set_is_walked_as_it_inflates() {
        let dir = tempfile::tempdir().expect("dir");
        let honest = written(
            dir.path(),
            "honest.dcm",
            &part10(DEFLATED, &data_set(None, None)),
        );
        assert!(check_lengths(&honest).expect("honest lengths"));
        // The file is one dicom-rs reads, so the walk checks what the parser will read.
        let obj = dicom_object::open_file(&honest).expect("dicom-rs reads it");
        assert_eq!(
            obj.element_by_name("Rows")
                .expect("rows")
                .to_int::<u16>()
                .ok(),
            Some(4)
        );

        // Found by mutation fuzzing: 835 bytes whose element claimed gigabytes, which dicom-rs
        // reserved and filled (3.2 GB, 5 s).
        let lie = written(
            dir.path(),
            "lie.dcm",
            &part10(DEFLATED, &data_set(Some(0xFFFF_FFF0), None)),
        );
        let e = check_lengths(&lie).expect_err("refused").to_string();
        for words in [
            "lie.dcm",
            "(0099,1000)",
            "of the inflated data set",
            "4294967280",
        ] {
            assert!(e.contains(words), "{words}: {e}");
        }
        // Read only up to the pixel data, the lie is still read: refused too.
        assert!(check_lengths_until(&lie, Some(PIXEL_DATA_TAG)).is_err());

        // Damage to the stream itself is the file's damage, named.
        let mut corrupt = part10(DEFLATED, &data_set(None, None));
        let meta = u32::from_le_bytes(corrupt[140..144].try_into().expect("4 bytes"));
        // The first block's type: 3, which no deflate stream has.
        corrupt[144 + meta as usize] = 0b111;
        let corrupt = written(dir.path(), "corrupt.dcm", &corrupt);
        let e = check_lengths(&corrupt).expect_err("refused").to_string();
        assert!(e.contains("corrupt.dcm") && e.contains("inflated"), "{e}");
    }

    #[test]
    fn a_reader_that_stops_at_the_pixel_data_inflates_no_further() {
        let dir = tempfile::tempdir().expect("dir");
        let ds = data_set(None, Some(0xFFFF_FFF0));
        let lie = written(dir.path(), "pixels.dcm", &part10(DEFLATED, &ds));
        assert!(check_lengths(&lie).is_err());
        // The pixel data inside the icon's item is not where a top-level reader stops: the
        // private element after it is still walked (above), the top-level pixel data is not.
        assert!(check_lengths_until(&lie, Some(PIXEL_DATA_TAG)).expect("stops before"));
        // In a file that is not deflated, skipping costs nothing: walked whole.
        let plain = written(dir.path(), "plain.dcm", &part10("1.2.840.10008.1.2.1", &ds));
        assert!(check_lengths_until(&plain, Some(PIXEL_DATA_TAG)).is_err());
    }

    #[test]
    fn implicit_vr_elements_are_read_with_the_dictionarys_vr() {
        let dir = tempfile::tempdir().expect("dir");
        let implicit = |tag: (u16, u16), value: &[u8], length: Option<u32>| {
            let mut out = Vec::new();
            out.extend(tag.0.to_le_bytes());
            out.extend(tag.1.to_le_bytes());
            out.extend(length.unwrap_or(value.len() as u32).to_le_bytes());
            out.extend(value);
            out
        };
        // A sequence of defined length (Referenced Image Sequence) is walked into: the element
        // in its item that claims gigabytes is refused, not skipped with the sequence.
        let inner = implicit((8, 0x1155), b"1.2.3\0", Some(0xFFFF_FFF0));
        let mut item = vec![0xFE, 0xFF, 0x00, 0xE0];
        item.extend((inner.len() as u32).to_le_bytes());
        item.extend(inner);
        let sq = implicit((8, 0x1140), &item, None);
        let path = written(dir.path(), "sq.dcm", &part10("1.2.840.10008.1.2", &sq));
        let e = check_lengths(&path).expect_err("refused").to_string();
        assert!(e.contains("(0008,1155)"), "{e}");
        // Rows is US: one byte of it loses dicom-rs its place.
        let rows = implicit((0x28, 0x10), &[4], None);
        let path = written(dir.path(), "rows.dcm", &part10("1.2.840.10008.1.2", &rows));
        let e = check_lengths(&path).expect_err("refused").to_string();
        assert!(e.contains("no multiple"), "{e}");
    }

    const EXPLICIT: &str = "1.2.840.10008.1.2.1";

    /// An item header: tag (FFFE,`element`) and a 32-bit length, no VR in any encoding.
    fn item(element: u16, length: u32) -> Vec<u8> {
        let mut out = vec![0xFE, 0xFF];
        out.extend(element.to_le_bytes());
        out.extend(length.to_le_bytes());
        out
    }

    #[test]
    fn delimiters_and_items_are_read_where_dicom_rs_reads_them() {
        let dir = tempfile::tempdir().expect("dir");
        let lie = element((0x99, 0x1000), b"OB", &[1, 2, 3, 4], Some(0xFFFF_FFF0));
        // Encapsulated pixel data ended by a sequence delimiter whose length is not 0 (found by
        // mutation fuzzing): dicom-rs reads no value after it, and the lie after it is its.
        let mut ds = element((0x28, 0x10), b"US", &4u16.to_le_bytes(), None);
        ds.extend(element(PIXEL_DATA, b"OB", &[], Some(UNDEFINED)));
        ds.extend(item(0xE000, 0));
        ds.extend(item(0xE000, 4));
        ds.extend([1, 2, 3, 4]);
        ds.extend(item(0xE0DD, 8));
        ds.extend(&lie);
        let path = written(dir.path(), "delimiter.dcm", &part10(EXPLICIT, &ds));
        let e = check_lengths(&path).expect_err("refused").to_string();
        assert!(e.contains("(0099,1000)"), "{e}");

        // An item header met inside an item, not at a sequence's level, is a value to dicom-rs
        // (found by mutation fuzzing): the walk skips it too and reads the lie after it.
        let in_item = |value: &[u8], after: &[u8]| {
            let mut body = element((8, 0x1150), b"UI", b"1.2.3\0", None);
            body.extend(item(0xE000, value.len() as u32));
            body.extend(value);
            body.extend(after);
            let mut items = item(0xE000, body.len() as u32);
            items.extend(body);
            let mut ds = element((8, 0x1140), b"SQ", &items, None);
            ds.extend(element((0x28, 0x10), b"US", &4u16.to_le_bytes(), None));
            ds
        };
        let ds = in_item(&[8, 0, 0, 1], &lie);
        let path = written(dir.path(), "item.dcm", &part10(EXPLICIT, &ds));
        let e = check_lengths(&path).expect_err("refused").to_string();
        assert!(e.contains("(0099,1000)"), "{e}");
        // And what looks like a lie inside that value is no element of the file: read.
        let ds = in_item(&lie, &[]);
        let path = written(dir.path(), "value.dcm", &part10(EXPLICIT, &ds));
        assert!(check_lengths(&path).expect("read as dicom-rs reads it"));
        dicom_object::open_file(&path).expect("dicom-rs reads it");
    }

    #[test]
    fn the_meta_group_ends_where_its_group_length_says() {
        let dir = tempfile::tempdir().expect("dir");
        // An element of another group inside the meta group's length, before the transfer
        // syntax (implicit VR): dicom-rs reads it as the meta group's, then the data set in
        // implicit VR (found by mutation fuzzing: the walk took the data set to start there).
        let mut meta = element((2, 1), b"OB", &[0, 1], None);
        meta.extend(element((4, 0x1130), b"CS", b"ID", None));
        meta.extend(element((2, 0x10), b"UI", b"1.2.840.10008.1.2\0", None));
        let mut file = vec![0u8; 128];
        file.extend(b"DICM");
        file.extend(element(
            (2, 0),
            b"UL",
            &(meta.len() as u32).to_le_bytes(),
            None,
        ));
        file.extend(meta);
        file.extend([0x99, 0, 0, 0x10]);
        file.extend(0xFFFF_FFF0u32.to_le_bytes());
        file.extend([1, 2, 3, 4]);
        let path = written(dir.path(), "meta.dcm", &file);
        let e = check_lengths(&path).expect_err("refused").to_string();
        assert!(e.contains("(0099,1000)"), "{e}");
        // Without a group length first, dicom-rs reads nothing of the file: left to it.
        let path = written(dir.path(), "no-group-length.dcm", &file[..132]);
        assert!(check_lengths(&path).expect("left to the parser"));
    }
}
