//! What the JPEG decoder is given: the file's markers walked (never its entropy-coded data
//! decoded) to tell a baseline frame from a progressive one and to find where it was cut.
//!
//! zune-jpeg, even strict, fills a scan that meets an end-of-image marker early with zero bits:
//! a frame cut short and closed by a proper EOI would decode to grey rows. A baseline frame is
//! therefore given without its final EOI (a complete scan needs none, and where the data simply
//! ends, strict mode reports it). A progressive frame needs its EOI (the decoder looks for a
//! marker after every scan), so it keeps it and is checked here instead: it must end with the EOI
//! after its last scan (a cut file does not), and its scans must bring every coefficient of every
//! component to its last bit (a file cut between scans and closed would not).
//! A progressive frame whose header claims more rows or columns than its scans code would decode
//! with the blocks never coded as zero (zune-jpeg fills them; found by mutation fuzzing): every
//! DC first scan's codes are read to its last MCU ([`super::jpeg_luma::dc_scan_complete`]), so
//! such a frame is refused too. Not read here, so not caught: progressive AC scans that stop
//! early (with end-of-band runs a few bytes code thousands of blocks, so nothing short of
//! decoding them says so), and a sequential frame that our own decoder (`jpeg_luma`, which
//! refuses a scan that stops early) declines, such as one with 16-bit quantisation tables, whose
//! scan meets its EOI early: zune-jpeg decodes the rest as zero there (mutation fuzzing,
//! 2026-12-05).

use super::RectifyError;

/// The bytes to decode: a baseline JPEG without its final EOI, a progressive one whole once its
/// scans are found complete. Bytes whose markers cannot be walked go to the decoder as a baseline
/// frame would (its errors then say what is wrong).
pub(crate) fn decoder_input(bytes: &[u8]) -> Result<&[u8], RectifyError> {
    let baseline = bytes.strip_suffix(&[0xFF, 0xD9]).unwrap_or(bytes);
    let Some(walk) = walk(bytes) else {
        return Ok(baseline);
    };
    if !walk.progressive {
        return Ok(baseline);
    }
    if !walk.ends_with_eoi {
        return Err(RectifyError::Jpeg(
            "the progressive file ends before its end-of-image marker: cut short (an interrupted \
             transfer or a full disk); take the frame again"
                .into(),
        ));
    }
    if let Some(scan) = walk.dc_short {
        return Err(RectifyError::Jpeg(format!(
            "the progressive file's DC scan {scan} ends before the last of the blocks its frame \
             header claims ({}x{} px): a damaged file; take the frame again",
            walk.width, walk.height
        )));
    }
    if let Some((component, k, bit)) = walk.first_incomplete() {
        return Err(RectifyError::Jpeg(format!(
            "the progressive file's scans stop before coefficient {k} of component {} is \
             complete (bits below {bit} never come): a file cut short and closed; take the \
             frame again",
            component + 1
        )));
    }
    Ok(bytes)
}

/// What the marker walk found.
#[derive(Default)]
struct Walk {
    progressive: bool,
    /// The file ends with the EOI, right after the last scan's data.
    ends_with_eoi: bool,
    /// Component ids of the frame header.
    components: Vec<u8>,
    /// Per component and coefficient: the lowest bit its scans have reached (`Al`), or −1 if no
    /// scan carried it yet.
    bits: Vec<[i8; 64]>,
    /// The frame's size and its components' sampling factors (h, v), in frame order.
    width: usize,
    height: usize,
    sampling: Vec<(usize, usize)>,
    /// The DC Huffman tables defined so far (DHT counts and symbols), by table number.
    dc_tables: [Option<([u8; 16], Vec<u8>)>; 4],
    restart_interval: usize,
    /// Scans seen, and the number (from 1) of the first DC first scan that ends before its last
    /// MCU.
    scans: usize,
    dc_short: Option<usize>,
}

impl Walk {
    fn first_incomplete(&self) -> Option<(usize, usize, i8)> {
        self.bits.iter().enumerate().find_map(|(c, bits)| {
            bits.iter()
                .position(|&b| b != 0)
                .map(|k| (c, k, bits[k].max(0)))
        })
    }

    /// Whether the DC first scan over `ids` (DC tables by `selectors`' high nibbles), its data
    /// at `data_start`, codes every block of the frame; false too for a component or table the
    /// file does not define.
    fn dc_scan_complete(
        &self,
        bytes: &[u8],
        ids: &[u8],
        selectors: &[u8],
        data_start: usize,
    ) -> bool {
        let max_hv = self
            .sampling
            .iter()
            .fold((0, 0), |(h, v), &(a, b)| (h.max(a), v.max(b)));
        let mut components = Vec::with_capacity(ids.len());
        for (id, sel) in ids.iter().zip(selectors) {
            let Some(c) = self.components.iter().position(|x| x == id) else {
                return false;
            };
            let Some(Some((counts, symbols))) = self.dc_tables.get(usize::from(sel >> 4)) else {
                return false;
            };
            components.push((self.sampling[c], counts, symbols.as_slice()));
        }
        super::jpeg_luma::dc_scan_complete(
            bytes,
            &super::jpeg_luma::DcScan {
                width: self.width,
                height: self.height,
                max_hv,
                components,
                restart_interval: self.restart_interval,
                data_start,
            },
        )
    }

    /// A progressive scan over `ids`, coefficients `ss..=se`, successive approximation `ah`/`al`.
    fn scan(&mut self, ids: &[u8], ss: usize, se: usize, ah: i8, al: i8) {
        if ss > se || se > 63 {
            return;
        }
        for id in ids {
            let Some(c) = self.components.iter().position(|x| x == id) else {
                continue;
            };
            for bit in self.bits[c][ss..=se].iter_mut() {
                // A first scan (ah = 0) starts a coefficient; a refinement takes it one bit on.
                if (ah == 0 && *bit < 0) || (ah > 0 && *bit == ah) {
                    *bit = al;
                }
            }
        }
    }
}

/// Walks the markers of a JPEG; `None` where they do not parse up to a frame header. A file
/// whose data runs out after its frame header is walked as far as it goes (`ends_with_eoi`
/// false).
fn walk(bytes: &[u8]) -> Option<Walk> {
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return None;
    }
    let mut w = Walk::default();
    match walk_markers(bytes, &mut w) {
        Some(()) => Some(w),
        None => (!w.components.is_empty()).then_some(w),
    }
}

/// The code of the marker at `pos` (0xFF, any fill 0xFFs, its code) and the offset after it;
/// `None` if there is none.
pub(super) fn marker_at(bytes: &[u8], mut pos: usize) -> Option<(u8, usize)> {
    if *bytes.get(pos)? != 0xFF {
        return None;
    }
    while bytes.get(pos) == Some(&0xFF) {
        pos += 1;
    }
    Some((*bytes.get(pos)?, pos + 1))
}

/// The markers from the one after SOI to the EOI; `None` where the data ends or stops parsing.
fn walk_markers(bytes: &[u8], w: &mut Walk) -> Option<()> {
    let mut pos = 2;
    loop {
        let code;
        (code, pos) = marker_at(bytes, pos)?;
        match code {
            0xD9 => {
                w.ends_with_eoi = pos == bytes.len();
                return Some(());
            }
            0x01 | 0xD0..=0xD7 => continue,
            _ => {}
        }
        let len = usize::from(u16::from_be_bytes([*bytes.get(pos)?, *bytes.get(pos + 1)?]));
        let segment = bytes.get(pos + 2..pos + len)?;
        pos += len;
        match code {
            // Frame headers (not DHT 0xC4, JPG 0xC8, DAC 0xCC).
            0xC0..=0xCF if !matches!(code, 0xC4 | 0xC8 | 0xCC) => {
                w.progressive = matches!(code, 0xC2 | 0xC6 | 0xCA | 0xCE);
                w.height = usize::from(u16::from_be_bytes([*segment.get(1)?, *segment.get(2)?]));
                w.width = usize::from(u16::from_be_bytes([*segment.get(3)?, *segment.get(4)?]));
                let n = usize::from(*segment.get(5)?);
                w.components = (0..n)
                    .map(|i| segment.get(6 + 3 * i).copied())
                    .collect::<Option<_>>()?;
                w.sampling = (0..n)
                    .map(|i| {
                        let hv = segment.get(7 + 3 * i)?;
                        Some((usize::from(hv >> 4), usize::from(hv & 15)))
                    })
                    .collect::<Option<_>>()?;
                w.bits = vec![[-1; 64]; n];
                if !w.progressive {
                    // Nothing more to learn: a baseline frame is decoded without its EOI.
                    return Some(());
                }
            }
            0xC4 => {
                // DHT: tables of class 0 (DC) are kept for the DC scans' check. A table that
                // does not parse is left to the decoder, whose error names it.
                let mut rest = segment;
                while let [tc_th, tail @ ..] = rest {
                    let Some(counts) = tail.get(..16).and_then(|c| <[u8; 16]>::try_from(c).ok())
                    else {
                        break;
                    };
                    let n: usize = counts.iter().map(|&c| usize::from(c)).sum();
                    let Some(symbols) = tail.get(16..16 + n) else {
                        break;
                    };
                    // (A table number past 3 is the decoder's to refuse.)
                    if let Some(slot) = w.dc_tables.get_mut(usize::from(tc_th & 15)) {
                        if tc_th >> 4 == 0 {
                            *slot = Some((counts, symbols.to_vec()));
                        }
                    }
                    rest = &tail[16 + n..];
                }
            }
            0xDD => {
                w.restart_interval =
                    usize::from(u16::from_be_bytes([*segment.first()?, *segment.get(1)?]));
            }
            0xDA => {
                let n = usize::from(*segment.first()?);
                let ids: Vec<u8> = (0..n)
                    .map(|i| segment.get(1 + 2 * i).copied())
                    .collect::<Option<_>>()?;
                let tail = segment.get(1 + 2 * n..1 + 2 * n + 3)?;
                let (ah, al) = ((tail[2] >> 4) as i8, (tail[2] & 15) as i8);
                w.scan(&ids, usize::from(tail[0]), usize::from(tail[1]), ah, al);
                w.scans += 1;
                if w.progressive && tail[0] == 0 && tail[1] == 0 && ah == 0 && w.dc_short.is_none()
                {
                    let selectors: Vec<u8> = (0..n)
                        .map(|i| segment.get(2 + 2 * i).copied())
                        .collect::<Option<_>>()?;
                    if !w.dc_scan_complete(bytes, &ids, &selectors, pos) {
                        w.dc_short = Some(w.scans);
                    }
                }
                // The entropy-coded data runs to the next marker that is not a restart marker
                // (0xFF 0x00 is a stuffed 0xFF byte).
                loop {
                    let at = pos + bytes.get(pos..)?.iter().position(|&b| b == 0xFF)?;
                    match *bytes.get(at + 1)? {
                        0x00 | 0xD0..=0xD7 | 0xFF => pos = at + 1,
                        _ => {
                            pos = at;
                            break;
                        }
                    }
                }
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_progressive_header_claiming_more_blocks_than_its_scans_code_is_refused() {
        use jpeg_encoder::{ColorType, Encoder};
        let (w, h) = (203u16, 157u16);
        let px = |x: u32, y: u32| [(x * 7) as u8, (y * 5) as u8, ((x + y) * 3) as u8];
        let rgb: Vec<u8> = (0..u32::from(w) * u32::from(h))
            .flat_map(|i| px(i % u32::from(w), i / u32::from(w)))
            .collect();
        let grey: Vec<u8> = rgb.iter().step_by(3).copied().collect();
        for (colour, restart) in [(true, 0), (true, 3), (false, 0), (false, 5)] {
            let mut jpeg = Vec::new();
            let mut enc = Encoder::new(&mut jpeg, 90);
            enc.set_progressive(true);
            enc.set_restart_interval(restart);
            match colour {
                true => enc.encode(&rgb, w, h, ColorType::Rgb),
                false => enc.encode(&grey, w, h, ColorType::Luma),
            }
            .unwrap();
            // Whole, it is given to the decoder as it is, and decodes.
            assert_eq!(decoder_input(&jpeg).unwrap(), &jpeg[..]);
            crate::rectify::decode_jpeg(&jpeg).unwrap();
            let sof = jpeg.windows(2).position(|m| m == [0xFF, 0xC2]).unwrap();
            // One more MCU row or column and more: blocks no scan codes.
            for (field, size) in [(5, h + 16), (5, 1000), (5, 65535), (7, w + 16), (7, 4096)] {
                let mut bad = jpeg.clone();
                bad[sof + field..sof + field + 2].copy_from_slice(&size.to_be_bytes());
                let e = decoder_input(&bad).unwrap_err().to_string();
                assert!(
                    e.contains("DC scan") && e.contains("damaged"),
                    "colour {colour}, restart {restart}, {field} = {size}: {e}"
                );
                assert!(crate::rectify::decode_jpeg(&bad).is_err());
            }
        }
    }

    fn jpeg(progressive: bool) -> Vec<u8> {
        let picture = image::RgbImage::from_fn(48, 40, |x, y| {
            image::Rgb([(x * 5) as u8, (y * 6) as u8, ((x + y) * 3) as u8])
        });
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
            .encode_image(&picture)
            .unwrap();
        if progressive {
            // A hand-made progressive header is not needed: flipping SOF0 to SOF2 makes the walk
            // treat the one interleaved scan as a DC-and-AC first scan (ah = al = 0).
            let sof = out.windows(2).position(|w| w == [0xFF, 0xC0]).unwrap();
            out[sof + 1] = 0xC2;
        }
        out
    }

    #[test]
    fn baseline_loses_its_eoi_and_progressive_keeps_it_when_complete() {
        let base = jpeg(false);
        assert_eq!(decoder_input(&base).unwrap(), &base[..base.len() - 2]);
        let prog = jpeg(true);
        assert_eq!(decoder_input(&prog).unwrap(), &prog[..]);
        // Cut: no EOI.
        let cut = &prog[..prog.len() - 40];
        let e = decoder_input(cut).unwrap_err().to_string();
        assert!(e.contains("cut short"), "{e}");
    }

    #[test]
    fn a_scan_script_that_stops_early_is_incomplete() {
        let mut w = Walk {
            progressive: true,
            ends_with_eoi: true,
            components: vec![1, 2, 3],
            bits: vec![[-1; 64]; 3],
            ..Walk::default()
        };
        // libjpeg's default script, without its last scan (luma AC refinement to bit 0).
        w.scan(&[1, 2, 3], 0, 0, 0, 1);
        w.scan(&[1], 1, 5, 0, 2);
        w.scan(&[3], 1, 63, 0, 1);
        w.scan(&[2], 1, 63, 0, 1);
        w.scan(&[1], 6, 63, 0, 2);
        w.scan(&[1], 1, 63, 2, 1);
        w.scan(&[1, 2, 3], 0, 0, 1, 0);
        w.scan(&[3], 1, 63, 1, 0);
        w.scan(&[2], 1, 63, 1, 0);
        assert_eq!(w.first_incomplete(), Some((0, 1, 1)));
        w.scan(&[1], 1, 63, 1, 0);
        assert_eq!(w.first_incomplete(), None);
    }
}
