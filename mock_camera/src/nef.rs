//! A Nikon D810 raw frame (NEF) of a rendered picture, so the raw path of layerwise can be tested
//! without a D810 on the bench and without a binary fixture in the repository.
//!
//! The file is what the body writes in the two 14-bit modes the daemon supports:
//! - a big-endian TIFF whose first IFD names the body (`NIKON CORPORATION`, `NIKON D810`), a
//!   SubIFD holding the RGGB Bayer mosaic, and an Exif IFD with a Nikon maker note;
//! - a maker note (type 2: `Nikon\0\x02\x10\0\0` then its own TIFF header) with the black level,
//!   the NEF compression, the serial number and shutter count, and the as-shot white balance as
//!   colour balance version 0204, enciphered the way Nikon does it;
//! - pixels either uncompressed (14 bits in 16-bit words) or lossless compressed (the difference
//!   coding with Nikon's 14-bit lossless Huffman table, as dcraw documents it).
//!
//! The sensor is 20 x 16 photosites larger than the picture: raw decoders crop a D810 frame by
//! 12 columns on the left, 8 on the right and 8 rows top and bottom (its JPEGs are 7360 x 4912 of
//! a 7380 x 4928 sensor), so the cropped raw lands exactly on the picture's pixel grid.

use image::RgbImage;

/// How the body stores the mosaic (the D810's 14-bit choices).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NefCompression {
    /// 14 bits per photosite in 16-bit big-endian words (NEF compression 2).
    Uncompressed,
    /// Nikon's lossless Huffman difference coding (NEF compression 3), the D810's default.
    Lossless,
}

/// What a raw frame is made with.
#[derive(Clone, Copy, Debug)]
pub struct NefOptions {
    pub compression: NefCompression,
    /// As-shot white balance multipliers (R, G, B), G = 1: the raw holds scene / multiplier.
    pub white_balance: [f64; 3],
    /// Black level of each site of the 2 x 2 pattern, row-major from the sensor's top-left
    /// photosite (R, G, G, B); a real D810 has [`D810_BLACK`] on all four.
    pub black_level: [u16; 4],
}

impl Default for NefOptions {
    fn default() -> Self {
        NefOptions {
            compression: NefCompression::Lossless,
            // A D810 under daylight, from a real frame's colour balance record.
            white_balance: [2.160_156_2, 1.0, 1.183_593_8],
            black_level: [D810_BLACK; 4],
        }
    }
}

/// The D810's black and white levels at 14 bits.
pub const D810_BLACK: u16 = 600;
pub const D810_WHITE: u16 = 15520;
/// Sensor margins that raw decoders crop from a D810 frame: left, top, right, bottom.
pub const D810_CROP: [u32; 4] = [12, 8, 8, 8];

/// XYZ (D65) → camera RGB of the D810, the matrix Adobe publishes for it (dcraw's adobe_coeff).
const D810_XYZ_TO_CAMERA: [[f64; 3]; 3] = [
    [0.9369, -0.3195, -0.0791],
    [-0.4488, 1.2430, 0.2301],
    [-0.0893, 0.1796, 0.6872],
];
/// Linear sRGB → XYZ (D65).
const SRGB_TO_XYZ: [[f64; 3]; 3] = [
    [0.412_456_4, 0.357_576_1, 0.180_437_5],
    [0.212_672_9, 0.715_152_2, 0.072_175_0],
    [0.019_333_9, 0.119_192_0, 0.950_304_1],
];

/// Linear sRGB → camera RGB with rows scaled to sum to one (white stays white), which is how raw
/// developers relate the two, so a developed frame gives back the picture's linear colour.
fn srgb_to_camera() -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3)
                .map(|k| D810_XYZ_TO_CAMERA[i][k] * SRGB_TO_XYZ[k][j])
                .sum();
        }
        let sum: f64 = row.iter().sum();
        row.iter_mut().for_each(|v| *v /= sum);
    }
    m
}

/// The sRGB transfer function undone: an 8-bit code value to linear light in 0..1.
pub fn srgb_to_linear(code: u8) -> f64 {
    let c = f64::from(code) / 255.0;
    if c <= 0.040_45 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The 14-bit mosaic of `picture` (sRGB-encoded) as the D810 would record it: RGGB, the black
/// level of each site, white at [`D810_WHITE`], with the sensor margins of [`D810_CROP`] filled
/// by the picture's edge. Row-major, `(width + 20) x (height + 16)`.
pub fn bayer_mosaic(
    picture: &RgbImage,
    white_balance: [f64; 3],
    black_level: [u16; 4],
) -> (u32, u32, Vec<u16>) {
    let (w, h) = picture.dimensions();
    let [left, top, right, bottom] = D810_CROP;
    let (sensor_w, sensor_h) = (w + left + right, h + top + bottom);
    let lut: Vec<f64> = (0..=255u8).map(srgb_to_linear).collect();
    let to_camera = srgb_to_camera();
    let mut mosaic = Vec::with_capacity(sensor_w as usize * sensor_h as usize);
    for row in 0..sensor_h {
        let y = row.saturating_sub(top).min(h.saturating_sub(1));
        for col in 0..sensor_w {
            let x = col.saturating_sub(left).min(w.saturating_sub(1));
            // RGGB: even rows R G, odd rows G B.
            let channel = match (row % 2, col % 2) {
                (0, 0) => 0,
                (1, 1) => 2,
                _ => 1,
            };
            let value = if w == 0 || h == 0 {
                0.0
            } else {
                let p = picture.get_pixel(x, y).0;
                let linear = [lut[p[0] as usize], lut[p[1] as usize], lut[p[2] as usize]];
                let camera: f64 = (0..3).map(|k| to_camera[channel][k] * linear[k]).sum();
                camera / white_balance[channel]
            };
            let black = f64::from(black_level[(row % 2 * 2 + col % 2) as usize]);
            let dn = black + value.clamp(0.0, 1.0) * (f64::from(D810_WHITE) - black);
            mosaic.push(dn.round() as u16);
        }
    }
    (sensor_w, sensor_h, mosaic)
}

/// A D810 NEF of `picture` (the picture is what the body's own JPEG would show).
pub fn encode_nef(picture: &RgbImage, options: &NefOptions) -> Vec<u8> {
    // The file stores the multipliers in 1/256 steps: the mosaic is made with those.
    let white_balance = options
        .white_balance
        .map(|m| (m * 256.0).round().clamp(1.0, 65535.0) / 256.0);
    let (width, height, mosaic) = bayer_mosaic(picture, white_balance, options.black_level);
    let (strip, nef_compression, tiff_compression) = match options.compression {
        NefCompression::Uncompressed => (
            mosaic
                .iter()
                .flat_map(|v| v.to_be_bytes())
                .collect::<Vec<u8>>(),
            2u16,
            1u16,
        ),
        NefCompression::Lossless => (
            lossless_14(&mosaic, width as usize, height as usize),
            3,
            34713,
        ),
    };
    let maker_note = maker_note(nef_compression, white_balance, options.black_level);

    let ifd0 = |raw_ifd: u32, exif_ifd: u32| {
        vec![
            Entry::ascii(0x010F, "NIKON CORPORATION"),
            Entry::ascii(0x0110, "NIKON D810"),
            Entry::longs(0x014A, &[raw_ifd]),
            Entry::longs(0x8769, &[exif_ifd]),
        ]
    };
    let raw_ifd = |strip_offset: u32| {
        vec![
            Entry::longs(0x00FE, &[0]),
            Entry::longs(0x0100, &[width]),
            Entry::longs(0x0101, &[height]),
            Entry::shorts(0x0102, &[14]),
            Entry::shorts(0x0103, &[tiff_compression]),
            // Colour filter array.
            Entry::shorts(0x0106, &[32803]),
            Entry::longs(0x0111, &[strip_offset]),
            Entry::shorts(0x0115, &[1]),
            Entry::longs(0x0116, &[height]),
            Entry::longs(0x0117, &[strip.len() as u32]),
            Entry::shorts(0x828D, &[2, 2]),
            Entry::bytes(0x828E, 1, &[0, 1, 1, 2]),
        ]
    };
    let exif_ifd = vec![
        Entry::shorts(0x8827, &[100]),
        Entry::bytes(0x927C, 7, &maker_note),
    ];
    // Block sizes do not depend on where the blocks go, so lay them out in one pass.
    let ifd0_at = 8u32;
    let raw_at = ifd0_at + ifd_len(&ifd0(0, 0));
    let exif_at = raw_at + ifd_len(&raw_ifd(0));
    let strip_at = exif_at + ifd_len(&exif_ifd);
    let mut file = b"MM\0\x2A".to_vec();
    file.extend_from_slice(&ifd0_at.to_be_bytes());
    file.extend(ifd_block(&ifd0(raw_at, exif_at), ifd0_at));
    file.extend(ifd_block(&raw_ifd(strip_at), raw_at));
    file.extend(ifd_block(&exif_ifd, exif_at));
    debug_assert_eq!(file.len(), strip_at as usize);
    file.extend(strip);
    file
}

/// The Nikon type-2 maker note: header, its own TIFF header (offsets count from there), one IFD.
fn maker_note(nef_compression: u16, white_balance: [f64; 3], black_level: [u16; 4]) -> Vec<u8> {
    // Colour balance 0204: "0204", 280 bytes, then 280 enciphered bytes whose bytes 6..14 hold
    // the R, G, G, B multipliers x 256, big-endian.
    let mut balance = vec![0u8; 284 + 280];
    balance[..4].copy_from_slice(b"0204");
    let mut plain = [0u8; 280];
    let levels = [
        white_balance[0],
        white_balance[1],
        white_balance[1],
        white_balance[2],
    ];
    for (i, m) in levels.iter().enumerate() {
        let v = (m * 256.0).round().clamp(1.0, 65535.0) as u16;
        plain[6 + 2 * i..8 + 2 * i].copy_from_slice(&v.to_be_bytes());
    }
    // The cipher's key streams start from one entry of each of dcraw's two 256-byte maps, picked
    // by the serial number (mod 256) and the xor of the shutter count's bytes. Serial "256" and
    // shutter count 0 pick entry 0 of both: 0xc1 and 0xa7.
    let ci: u32 = 0xC1;
    let mut cj: u32 = 0xA7;
    for (ck, (out, p)) in (0x60_u32..).zip(balance[284..].iter_mut().zip(plain)) {
        cj = cj.wrapping_add(ci.wrapping_mul(ck));
        *out = p ^ (cj as u8);
    }
    let mut entries = vec![
        Entry::ascii(0x001D, "256"),
        Entry::shorts(0x003D, &black_level),
        Entry::shorts(0x0093, &[nef_compression]),
        Entry::bytes(0x0097, 7, &balance),
        Entry::longs(0x00A7, &[0]),
    ];
    if nef_compression == 3 {
        // Linearization table: version 0x46 0x30 (lossless, no curve), the four vertical
        // predictors, and an empty curve.
        entries.push(Entry::bytes(
            0x0096,
            7,
            &[0x46, 0x30, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        ));
        entries.sort_by_key(|e| e.tag);
    }
    let mut note = b"Nikon\0\x02\x10\0\0MM\0\x2A".to_vec();
    note.extend_from_slice(&8u32.to_be_bytes());
    note.extend(ifd_block(&entries, 8));
    note
}

/// Nikon's 14-bit lossless coding: each photosite minus the one two columns to its left (the first
/// two of a row: minus the same column two rows up), the difference sent as a JPEG-style category
/// (Huffman coded with Nikon's table) and its low bits, MSB first, no byte stuffing.
/// How many Huffman codes have each length 1..=16, and the categories they code in order: dcraw's
/// `nikon_tree` entry for 14-bit lossless.
const COUNTS: [u8; 16] = [0, 1, 4, 2, 2, 3, 1, 2, 0, 0, 0, 0, 0, 0, 0, 0];
const CATEGORIES: [u8; 15] = [7, 6, 8, 5, 9, 4, 10, 3, 11, 12, 2, 0, 1, 13, 14];

fn lossless_14(mosaic: &[u16], width: usize, height: usize) -> Vec<u8> {
    let mut codes = [(0u32, 0u32); 16];
    let mut code = 0u32;
    let mut k = 0;
    for (len, &count) in COUNTS.iter().enumerate() {
        for _ in 0..count {
            codes[CATEGORIES[k] as usize] = (code, len as u32 + 1);
            code += 1;
            k += 1;
        }
        code <<= 1;
    }
    let mut bits = BitWriter::default();
    let mut put = |diff: i32| {
        let category = 32 - diff.unsigned_abs().leading_zeros();
        let (code, len) = codes[category as usize];
        bits.put(code, len);
        if category > 0 {
            let low = if diff < 0 {
                diff + (1 << category) - 1
            } else {
                diff
            };
            bits.put(low as u32, category);
        }
    };
    let mut up = [[0i32; 2]; 2];
    for row in 0..height {
        let line = &mosaic[row * width..(row + 1) * width];
        for col in 0..width {
            let v = i32::from(line[col]);
            let prediction = if col < 2 {
                std::mem::replace(&mut up[row & 1][col], v)
            } else {
                i32::from(line[col - 2])
            };
            put(v - prediction);
        }
    }
    bits.finish()
}

#[derive(Default)]
struct BitWriter {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl BitWriter {
    fn put(&mut self, value: u32, len: u32) {
        self.acc = (self.acc << len) | u64::from(value & ((1u32 << len) - 1));
        self.n += len;
        while self.n >= 8 {
            self.n -= 8;
            self.out.push((self.acc >> self.n) as u8);
        }
    }

    fn finish(mut self) -> Vec<u8> {
        if self.n > 0 {
            self.out.push((self.acc << (8 - self.n)) as u8);
        }
        // Decoders read ahead; real files end with padding too.
        self.out.extend_from_slice(&[0; 16]);
        self.out
    }
}

/// One TIFF directory entry, its value already in big-endian bytes.
struct Entry {
    tag: u16,
    kind: u16,
    count: u32,
    value: Vec<u8>,
}

impl Entry {
    fn ascii(tag: u16, text: &str) -> Entry {
        let mut value = text.as_bytes().to_vec();
        value.push(0);
        Entry::bytes(tag, 2, &value)
    }

    fn bytes(tag: u16, kind: u16, value: &[u8]) -> Entry {
        Entry {
            tag,
            kind,
            count: value.len() as u32,
            value: value.to_vec(),
        }
    }

    fn shorts(tag: u16, values: &[u16]) -> Entry {
        Entry {
            tag,
            kind: 3,
            count: values.len() as u32,
            value: values.iter().flat_map(|v| v.to_be_bytes()).collect(),
        }
    }

    fn longs(tag: u16, values: &[u32]) -> Entry {
        Entry {
            tag,
            kind: 4,
            count: values.len() as u32,
            value: values.iter().flat_map(|v| v.to_be_bytes()).collect(),
        }
    }
}

fn padded(n: usize) -> usize {
    n + n % 2
}

/// Bytes of a directory with the values that do not fit in its entries.
fn ifd_len(entries: &[Entry]) -> u32 {
    let values: usize = entries
        .iter()
        .filter(|e| e.value.len() > 4)
        .map(|e| padded(e.value.len()))
        .sum();
    (2 + 12 * entries.len() + 4 + values) as u32
}

/// A directory placed at `at` (in the offsets of its TIFF), followed by its long values.
fn ifd_block(entries: &[Entry], at: u32) -> Vec<u8> {
    let mut head = (entries.len() as u16).to_be_bytes().to_vec();
    let mut tail = Vec::new();
    let mut next_value = at as usize + 2 + 12 * entries.len() + 4;
    for e in entries {
        head.extend_from_slice(&e.tag.to_be_bytes());
        head.extend_from_slice(&e.kind.to_be_bytes());
        head.extend_from_slice(&e.count.to_be_bytes());
        if e.value.len() <= 4 {
            let mut inline = [0u8; 4];
            inline[..e.value.len()].copy_from_slice(&e.value);
            head.extend_from_slice(&inline);
        } else {
            head.extend_from_slice(&(next_value as u32).to_be_bytes());
            tail.extend_from_slice(&e.value);
            if e.value.len() % 2 == 1 {
                tail.push(0);
            }
            next_value += padded(e.value.len());
        }
    }
    head.extend_from_slice(&0u32.to_be_bytes());
    head.extend(tail);
    head
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mosaic_of_grey_is_neutral_after_white_balance() {
        let picture = RgbImage::from_pixel(6, 4, image::Rgb([128, 128, 128]));
        let wb = [2.0, 1.0, 1.5];
        let (w, h, m) = bayer_mosaic(&picture, wb, [D810_BLACK; 4]);
        assert_eq!((w, h), (26, 20));
        let lin = srgb_to_linear(128);
        let range = f64::from(D810_WHITE - D810_BLACK);
        let at = |x: usize, y: usize| (f64::from(m[y * w as usize + x]) - 600.0) / range;
        // R, G, B photosites times their multipliers all give the grey back.
        for (x, y, mult) in [(12, 8, 2.0), (13, 8, 1.0), (13, 9, 1.5)] {
            assert!((at(x, y) * mult - lin).abs() < 2e-4, "{x},{y}");
        }
    }

    #[test]
    fn lossless_coding_decodes_back() {
        // A reference decoder written from dcraw's description: categories then low bits.
        let (w, h) = (10usize, 3usize);
        let mosaic: Vec<u16> = (0..w * h).map(|i| ((i * 7919) % 16384) as u16).collect();
        let coded = lossless_14(&mosaic, w, h);
        let mut table = Vec::new();
        let (mut code, mut k) = (0u32, 0);
        for (len, &count) in COUNTS.iter().enumerate() {
            for _ in 0..count {
                table.push((code, len as u32 + 1, CATEGORIES[k]));
                code += 1;
                k += 1;
            }
            code <<= 1;
        }
        let mut pos = 0usize;
        let mut bit = |n: u32| {
            let mut v = 0u32;
            for _ in 0..n {
                v = (v << 1) | u32::from((coded[pos / 8] >> (7 - pos % 8)) & 1);
                pos += 1;
            }
            v
        };
        let mut out = vec![0i32; w * h];
        let mut up = [[0i32; 2]; 2];
        for row in 0..h {
            for col in 0..w {
                let (mut c, mut l) = (0u32, 0u32);
                let category = loop {
                    c = (c << 1) | bit(1);
                    l += 1;
                    if let Some(t) = table.iter().find(|t| t.0 == c && t.1 == l) {
                        break u32::from(t.2);
                    }
                };
                let mut diff = if category == 0 {
                    0
                } else {
                    bit(category) as i32
                };
                if category > 0 && diff & (1 << (category - 1)) == 0 {
                    diff -= (1 << category) - 1;
                }
                let v = if col < 2 {
                    up[row & 1][col] += diff;
                    up[row & 1][col]
                } else {
                    out[row * w + col - 2] + diff
                };
                out[row * w + col] = v;
            }
        }
        let expected: Vec<i32> = mosaic.iter().map(|&v| i32::from(v)).collect();
        assert_eq!(out, expected);
    }

    #[test]
    fn file_starts_as_a_big_endian_tiff_naming_the_body() {
        let picture = RgbImage::from_pixel(8, 6, image::Rgb([10, 20, 30]));
        for compression in [NefCompression::Uncompressed, NefCompression::Lossless] {
            let nef = encode_nef(
                &picture,
                &NefOptions {
                    compression,
                    ..NefOptions::default()
                },
            );
            assert!(nef.starts_with(b"MM\0\x2A"));
            let has = |needle: &[u8]| nef.windows(needle.len()).any(|w| w == needle);
            assert!(has(b"NIKON D810\0"));
            assert!(has(b"Nikon\0\x02\x10\0\0MM"));
        }
    }
}
