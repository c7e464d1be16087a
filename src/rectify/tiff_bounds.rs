//! A TIFF-based frame (a NEF, a TIFF picture) checked before any decoder reads it.
//!
//! rawler follows a file's chain of directories without looking for a loop (a directory that
//! points to itself grows its list until the process aborts), and reserves each entry's values,
//! `count` of them, before reading them (a count of 4 billion reserves up to 32 GB). So every
//! directory a decoder may read is walked here first, with the file's own bytes as the only
//! bound: each directory once (a loop is refused), at most [`MAX_DIRECTORIES`] of them, every
//! entry's values inside the file, and no directory that claims a picture larger than a camera
//! frame ([`super::MAX_FRAME_PIXELS`]). The walk reads only the bytes it is given and allocates
//! only its list of visited directories.
//!
//! Directories reached: the main chain, the sub-directories rawler opens (SubIFDs, Exif, GPS and
//! the tag it also takes for one, InterColorProfile; one at offset 0 too, where rawler reads the
//! file's header as a directory), their chains, and a Nikon maker note (an embedded TIFF whose
//! offsets count from its own header).
//!
//! Refused because rawler would read them otherwise than this walk does (all found by mutation
//! fuzzing, each reserving gigabytes or, for the mosaics, giving a different result from call to
//! call): a picture size that is not SHORT or LONG; a sub-directory tag of a type rawler does
//! not know (it opens a directory at an offset made of the value's first byte); a maker note
//! that is not a Nikon one (rawler opens it as a directory of its own kind); and a second
//! directory with a colour filter pattern (rawler takes one of them in a hash map's order).

use super::RectifyError;

/// Directories a frame may have: a NEF has about ten; a loop or a crafted fan-out is refused.
pub(crate) const MAX_DIRECTORIES: usize = 256;

/// Entries rawler reads from one directory at most (its `MAX_IFD_ENTRIES`).
const MAX_ENTRIES: usize = 4096;

/// Tags whose values point at sub-directories that rawler opens.
const SUB_DIRECTORY_TAGS: [u16; 4] = [330, 34665, 34853, 34675];
const MAKER_NOTE: u16 = 0x927C;
const IMAGE_WIDTH: u16 = 256;
const IMAGE_LENGTH: u16 = 257;
/// The raw mosaic's colour filter pattern: in one directory of a NEF.
const CFA_PATTERN: u16 = 33422;

/// Bytes per value of TIFF field type `typ` (rawler reads an unknown type as bytes).
fn value_size(typ: u16) -> u64 {
    match typ {
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        5 | 10 | 12 => 8,
        _ => 1,
    }
}

/// Whether `bytes` open like a TIFF (either byte order), as NEF and TIFF frames do.
pub(crate) fn is_tiff(bytes: &[u8]) -> bool {
    bytes.starts_with(b"MM\0\x2A") || bytes.starts_with(b"II\x2A\0")
}

/// Walks every directory of a TIFF-based frame; see the module docs. `Ok` for bytes that are not
/// a TIFF.
pub(crate) fn check(bytes: &[u8]) -> Result<(), RectifyError> {
    if !is_tiff(bytes) {
        return Ok(());
    }
    let mut walk = Walk {
        bytes,
        big_endian: bytes[0] == b'M',
        visited: Vec::new(),
        mosaics: 0,
    };
    let first = walk.u32_at(4).unwrap_or(0);
    walk.chain(0, first)
}

struct Walk<'a> {
    bytes: &'a [u8],
    big_endian: bool,
    /// File offsets of the directories seen.
    visited: Vec<u64>,
    /// Directories with a colour filter pattern seen.
    mosaics: usize,
}

fn refused(what: String) -> RectifyError {
    RectifyError::Tiff(what)
}

impl Walk<'_> {
    /// The `N` bytes at `at` in the file's byte order, most significant first.
    fn be_bytes<const N: usize>(&self, at: u64) -> Option<[u8; N]> {
        let at = usize::try_from(at).ok()?;
        let mut b: [u8; N] = self.bytes.get(at..at.checked_add(N)?)?.try_into().ok()?;
        if !self.big_endian {
            b.reverse();
        }
        Some(b)
    }

    fn u16_at(&self, at: u64) -> Option<u16> {
        self.be_bytes(at).map(u16::from_be_bytes)
    }

    fn u32_at(&self, at: u64) -> Option<u32> {
        self.be_bytes(at).map(u32::from_be_bytes)
    }

    /// The chain of directories from `offset` (relative to `base`), each followed by the next
    /// it names, until one names 0. The first is read even at offset 0, as rawler reads a
    /// sub-directory there (the file's header taken for a directory).
    fn chain(&mut self, base: u64, mut offset: u32) -> Result<(), RectifyError> {
        while let Some(next) = self.directory(base, offset)? {
            if next == 0 {
                break;
            }
            offset = next;
        }
        Ok(())
    }

    /// One directory (and, depth first, the sub-directories its entries name); returns the next
    /// directory's offset, `None` where the directory lies beyond the file (a decoder stops
    /// there: nothing is read, nothing reserved).
    fn directory(&mut self, base: u64, offset: u32) -> Result<Option<u32>, RectifyError> {
        let at = base + u64::from(offset);
        let len = self.bytes.len() as u64;
        if at >= len {
            return Ok(None);
        }
        if let Some(first) = self.visited.iter().position(|&v| v == at) {
            return Err(refused(format!(
                "a directory leads back to the directory at byte {at} (directory {} of the \
                 file): a loop, so this is a damaged or crafted file, not a camera frame",
                first + 1
            )));
        }
        if self.visited.len() >= MAX_DIRECTORIES {
            return Err(refused(format!(
                "more than {MAX_DIRECTORIES} directories (a camera frame has about ten): a \
                 damaged or crafted file"
            )));
        }
        self.visited.push(at);
        let Some(count) = self.u16_at(at) else {
            return Ok(None);
        };
        let (mut width, mut height) = (None, None);
        let mut subs = Vec::new();
        let mut entries_end = at + 2;
        for i in 0..usize::from(count).min(MAX_ENTRIES) {
            let entry = at + 2 + 12 * i as u64;
            if entry + 12 > len {
                // The directory runs past the end: decoders stop reading it here.
                break;
            }
            entries_end = entry + 12;
            let tag = self.u16_at(entry).unwrap_or(0);
            let typ = self.u16_at(entry + 2).unwrap_or(0);
            let n = u64::from(self.u32_at(entry + 4).unwrap_or(0));
            let size = n * value_size(typ);
            let data = if size <= 4 {
                entry + 8
            } else {
                let data = base + u64::from(self.u32_at(entry + 8).unwrap_or(0));
                if data + size > len {
                    return Err(refused(format!(
                        "the directory at byte {at}, entry {} (tag {tag}): {n} values of type \
                         {typ} ({size} bytes) at byte {data}, beyond the file's {len} bytes: a \
                         damaged or crafted file",
                        i + 1
                    )));
                }
                data
            };
            let first_value = || match typ {
                3 => self.u16_at(data).map(u64::from),
                4 => self.u32_at(data).map(u64::from),
                _ => None,
            };
            let damaged = |what: &str| {
                refused(format!(
                    "the directory at byte {at}, entry {} (tag {tag}): {what}: a damaged or \
                     crafted file",
                    i + 1
                ))
            };
            match tag {
                IMAGE_WIDTH | IMAGE_LENGTH if !matches!(typ, 3 | 4) => {
                    // A decoder would still read it as a size, past the check below.
                    return Err(damaged(&format!(
                        "a picture size of type {typ}, where TIFF has SHORT (3) or LONG (4)"
                    )));
                }
                IMAGE_WIDTH => width = first_value(),
                IMAGE_LENGTH => height = first_value(),
                CFA_PATTERN => {
                    self.mosaics += 1;
                    if self.mosaics > 1 {
                        // rawler would take one of them at random (a hash map's order).
                        return Err(damaged("a second raw mosaic (colour filter pattern)"));
                    }
                }
                MAKER_NOTE if typ == 7 => {
                    let note = &self.bytes[data as usize..(data + size) as usize];
                    if !(note.starts_with(b"Nikon\0\x02") && note.len() >= 18) {
                        // rawler opens any other maker note as a directory of its own kind.
                        return Err(damaged(
                            "a maker note that is not a Nikon one (layerwise reads the frames \
                             of a Nikon D810)",
                        ));
                    }
                    subs.push(SubDirectory::Nikon(data + 10));
                }
                t if SUB_DIRECTORY_TAGS.contains(&t) => match typ {
                    4 => {
                        for k in 0..n {
                            let offset = self.u32_at(data + 4 * k).unwrap_or(0);
                            subs.push(SubDirectory::At(base, offset));
                        }
                    }
                    // rawler opens an opaque value (an ICC profile) as a directory.
                    7 => subs.push(SubDirectory::At(0, data as u32)),
                    // Types rawler does not know (0, 13 and above) it opens at an offset made
                    // of the value's first byte.
                    0 | 13.. => {
                        return Err(damaged(&format!(
                            "a sub-directory of type {typ}, where TIFF has LONG (4)"
                        )))
                    }
                    // rawler ignores a sub-directory of another known type.
                    _ => {}
                },
                _ => {}
            }
        }
        if let (Some(w), Some(h)) = (width, height) {
            if w.saturating_mul(h) > super::MAX_FRAME_PIXELS as u64 {
                return Err(refused(format!(
                    "the directory at byte {at} describes a {w} x {h} picture, more than the \
                     {} Mpx a camera frame may have (a D810 frame is 36 Mpx)",
                    super::MAX_FRAME_PIXELS >> 20
                )));
            }
        }
        let next = self.u32_at(entries_end).unwrap_or(0);
        for sub in subs {
            match sub {
                SubDirectory::At(base, offset) => self.chain(base, offset)?,
                SubDirectory::Nikon(header) => self.maker_note(header)?,
            }
        }
        Ok(Some(next))
    }

    /// A Nikon maker note: a TIFF of its own at `header` (its byte order, offsets counted from
    /// it; rawler reads its first directory at 8).
    fn maker_note(&mut self, header: u64) -> Result<(), RectifyError> {
        let order = self
            .bytes
            .get(header as usize..header as usize + 2)
            .unwrap_or_default();
        let outer = self.big_endian;
        self.big_endian = order != b"II";
        let result = self.chain(header, 8);
        self.big_endian = outer;
        result
    }
}

enum SubDirectory {
    /// A directory at an offset from a base.
    At(u64, u32),
    /// A Nikon maker note whose TIFF header is at this file offset.
    Nikon(u64),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A directory entry: tag, type, count, value (or offset).
    type Entry = (u16, u16, u32, u32);

    /// A little-endian TIFF: header, then directories of entries at the offsets given, each
    /// followed by its next-directory offset.
    fn tiff(dirs: &[(u32, &[Entry], u32)], len: usize) -> Vec<u8> {
        let mut b = vec![0u8; len];
        b[..4].copy_from_slice(b"II\x2A\0");
        b[4..8].copy_from_slice(&dirs[0].0.to_le_bytes());
        for (at, entries, next) in dirs {
            let mut p = *at as usize;
            b[p..p + 2].copy_from_slice(&(entries.len() as u16).to_le_bytes());
            p += 2;
            for (tag, typ, n, v) in entries.iter() {
                b[p..p + 2].copy_from_slice(&tag.to_le_bytes());
                b[p + 2..p + 4].copy_from_slice(&typ.to_le_bytes());
                b[p + 4..p + 8].copy_from_slice(&n.to_le_bytes());
                b[p + 8..p + 12].copy_from_slice(&v.to_le_bytes());
                p += 12;
            }
            b[p..p + 4].copy_from_slice(&next.to_le_bytes());
        }
        b
    }

    fn message(bytes: &[u8]) -> String {
        match check(bytes) {
            Err(e) => e.to_string(),
            Ok(()) => String::new(),
        }
    }

    #[test]
    fn a_directory_that_points_to_itself_is_refused() {
        // 30 bytes: header, one directory of one entry whose next directory is itself.
        let looped = tiff(&[(8, &[(256, 3, 1, 64)], 8)], 30);
        assert_eq!(looped.len(), 30);
        assert!(message(&looped).contains("loop"), "{}", message(&looped));
        // Two directories pointing at each other, and a sub-directory pointing at its parent.
        let pair = tiff(
            &[(8, &[(256, 3, 1, 64)], 40), (40, &[(257, 3, 1, 64)], 8)],
            80,
        );
        assert!(message(&pair).contains("loop"));
        let parent = tiff(&[(8, &[(330, 4, 1, 8)], 0)], 40);
        assert!(message(&parent).contains("loop"));
    }

    #[test]
    fn values_beyond_the_file_and_huge_pictures_are_refused() {
        // 4 billion doubles: 32 GB a decoder would reserve.
        let huge = tiff(&[(8, &[(300, 12, u32::MAX, 8)], 0)], 64);
        assert!(
            message(&huge).contains("beyond the file"),
            "{}",
            message(&huge)
        );
        let wide = tiff(&[(8, &[(256, 4, 1, 1 << 20), (257, 4, 1, 1 << 20)], 0)], 64);
        assert!(
            message(&wide).contains("1048576 x 1048576"),
            "{}",
            message(&wide)
        );
        // A proper small TIFF passes, and so do bytes that are not a TIFF.
        let fine = tiff(&[(8, &[(256, 3, 1, 64), (257, 3, 1, 48)], 0)], 64);
        assert!(check(&fine).is_ok());
        assert!(check(b"\xff\xd8\xff").is_ok());
    }

    #[test]
    fn entries_a_decoder_would_read_otherwise_than_the_walk_are_refused() {
        // Each found by mutation fuzzing: rawler reserved gigabytes or took a random directory.
        let cases: [(&[Entry], &str); 5] = [
            // A size as a RATIONAL: the size check did not see it.
            (
                &[(256, 5, 1, 40), (257, 3, 1, 48)],
                "a picture size of type 5",
            ),
            // SubIFDs and an ICC profile of types rawler does not know.
            (&[(330, 14, 1, 40)], "a sub-directory of type 14"),
            (&[(34675, 15, 4, 0)], "a sub-directory of type 15"),
            // A maker note that is not Nikon's (here: one byte off).
            (&[(0x927C, 7, 20, 41)], "not a Nikon one"),
            // Two mosaics.
            (
                &[(33422, 1, 4, 0x0102_0100), (33422, 1, 4, 0x0102_0100)],
                "a second raw mosaic",
            ),
        ];
        for (entries, expected) in cases {
            let mut bytes = tiff(&[(8, entries, 0)], 96);
            bytes[40..47].copy_from_slice(b"Nikon\0\x02");
            let m = message(&bytes);
            assert!(
                m.contains(expected) && m.contains("entry"),
                "{expected}: {m}"
            );
        }
        // A Nikon maker note where it belongs passes.
        let mut nikon = tiff(&[(8, &[(0x927C, 7, 20, 40)], 0)], 96);
        nikon[40..47].copy_from_slice(b"Nikon\0\x02");
        nikon[50..54].copy_from_slice(b"II\x2A\0");
        check(&nikon).unwrap();
        // A sub-directory at offset 0 is walked (rawler reads the header as one).
        let at_zero = tiff(&[(8, &[(330, 4, 1, 0)], 0)], 64);
        let mut walk = Walk {
            bytes: &at_zero,
            big_endian: false,
            visited: Vec::new(),
            mosaics: 0,
        };
        let _ = walk.chain(0, 8);
        assert!(walk.visited.contains(&0), "{:?}", walk.visited);
    }

    #[test]
    fn a_real_tiff_and_a_mock_nef_pass() {
        let picture = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([x as u8, y as u8, 7]));
        let mut tif = std::io::Cursor::new(Vec::new());
        picture
            .write_to(&mut tif, image::ImageFormat::Tiff)
            .unwrap();
        check(tif.get_ref()).unwrap();
        let nef = mock_camera::nef::encode_nef(&picture, &Default::default());
        check(&nef).unwrap();
    }
}
