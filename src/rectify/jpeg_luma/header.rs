//! The markers before the first scan: quantisation and Huffman tables, the frame header, the
//! restart interval and the scan header. Anything this decoder does not handle (or cannot parse)
//! makes [`parse`] return `None`: the frame then goes to zune-jpeg, whose errors say what is
//! wrong.

use super::bits::HuffTable;
use super::zigzag::ZIGZAG;
use crate::rectify::jpeg_scan::marker_at;

/// One component of the frame, as the scan codes it.
#[derive(Clone, Copy, Debug)]
pub(super) struct Component {
    pub(super) h: usize,
    pub(super) v: usize,
    /// DC and AC Huffman table indices (0..4).
    pub(super) dc: usize,
    pub(super) ac: usize,
}

/// What the decoder needs to decode the first scan.
pub(super) struct Header {
    pub(super) width: usize,
    pub(super) height: usize,
    /// In scan order; the first is the luma (Y) component.
    pub(super) components: Vec<Component>,
    /// The luma's quantisation table, natural order.
    pub(super) luma_quant: [u16; 64],
    pub(super) dc_tables: [Option<HuffTable>; 4],
    pub(super) ac_tables: [Option<HuffTable>; 4],
    /// MCUs between restart markers (0: none).
    pub(super) restart_interval: usize,
    /// Offset of the entropy-coded data of the first scan.
    pub(super) data_start: usize,
}

/// A frame component as the frame header gives it.
struct FrameComponent {
    id: u8,
    h: usize,
    v: usize,
    tq: usize,
}

/// The header of a baseline or extended sequential 8-bit JPEG with one component, or three in one
/// interleaved scan whose first component has the largest sampling factors; `None` for any other
/// file (or one whose markers do not parse).
pub(super) fn parse(bytes: &[u8]) -> Option<Header> {
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return None;
    }
    let mut quant: [Option<[u16; 64]>; 4] = [None; 4];
    let mut dc_tables: [Option<HuffTable>; 4] = Default::default();
    let mut ac_tables: [Option<HuffTable>; 4] = Default::default();
    let mut frame: Option<(usize, usize, Vec<FrameComponent>)> = None;
    let mut restart_interval = 0;
    let mut adobe_rgb = false;
    let mut pos = 2;
    loop {
        let code;
        (code, pos) = marker_at(bytes, pos)?;
        if matches!(code, 0x01 | 0xD0..=0xD9) {
            // TEM, RSTn, SOI, EOI: no segment; none belongs before a scan.
            return None;
        }
        let len = usize::from(u16::from_be_bytes([*bytes.get(pos)?, *bytes.get(pos + 1)?]));
        let segment = bytes.get(pos + 2..pos + len.checked_sub(2)? + 2)?;
        pos += len;
        match code {
            0xDB => parse_dqt(segment, &mut quant)?,
            0xC4 => parse_dht(segment, &mut dc_tables, &mut ac_tables)?,
            0xC0 | 0xC1 => {
                if frame.is_some() {
                    return None;
                }
                frame = Some(parse_sof(segment)?);
            }
            // Every other frame type (progressive, lossless, arithmetic coding …), and DAC.
            0xC2..=0xCF => return None,
            0xDD => {
                restart_interval =
                    usize::from(u16::from_be_bytes([*segment.first()?, *segment.get(1)?]));
            }
            // Adobe APP14: transform 0 on three components means RGB, not YCbCr.
            0xEE if segment.starts_with(b"Adobe") && segment.get(11) == Some(&0) => {
                adobe_rgb = true;
            }
            0xDA => {
                let (width, height, comps) = frame?;
                if comps.len() == 3 && (adobe_rgb || comps.iter().map(|c| c.id).eq(*b"RGB")) {
                    return None;
                }
                let components = parse_sos(segment, &comps, &dc_tables, &ac_tables)?;
                let luma_quant = quant[comps[0].tq]?;
                return Some(Header {
                    width,
                    height,
                    components,
                    luma_quant,
                    dc_tables,
                    ac_tables,
                    restart_interval,
                    data_start: pos,
                });
            }
            _ => {}
        }
    }
}

/// DQT: 8-bit tables only (16-bit ones belong to 12-bit frames).
fn parse_dqt(mut segment: &[u8], quant: &mut [Option<[u16; 64]>; 4]) -> Option<()> {
    while let Some((&pq_tq, rest)) = segment.split_first() {
        let (pq, tq) = (pq_tq >> 4, usize::from(pq_tq & 15));
        if pq != 0 || tq > 3 {
            return None;
        }
        let values = rest.get(..64)?;
        let mut table = [0u16; 64];
        for (k, &v) in values.iter().enumerate() {
            table[usize::from(ZIGZAG[k])] = u16::from(v);
        }
        quant[tq] = Some(table);
        segment = &rest[64..];
    }
    Some(())
}

fn parse_dht(
    mut segment: &[u8],
    dc: &mut [Option<HuffTable>; 4],
    ac: &mut [Option<HuffTable>; 4],
) -> Option<()> {
    while let Some((&tc_th, rest)) = segment.split_first() {
        let (tc, th) = (tc_th >> 4, usize::from(tc_th & 15));
        if tc > 1 || th > 3 {
            return None;
        }
        let counts: [u8; 16] = rest.get(..16)?.try_into().ok()?;
        let n: usize = counts.iter().map(|&c| usize::from(c)).sum();
        let symbols = rest.get(16..16 + n)?;
        let table = HuffTable::new(&counts, symbols, tc == 1)?;
        if tc == 0 {
            dc[th] = Some(table);
        } else {
            ac[th] = Some(table);
        }
        segment = &rest[16 + n..];
    }
    Some(())
}

/// SOF0/SOF1: 8-bit precision, one or three components, sampling factors 1..=4.
fn parse_sof(segment: &[u8]) -> Option<(usize, usize, Vec<FrameComponent>)> {
    if *segment.first()? != 8 {
        return None;
    }
    let height = usize::from(u16::from_be_bytes([*segment.get(1)?, *segment.get(2)?]));
    let width = usize::from(u16::from_be_bytes([*segment.get(3)?, *segment.get(4)?]));
    let n = usize::from(*segment.get(5)?);
    // Height 0 (a DNL marker gives it after the scan) is left to zune.
    if width == 0 || height == 0 || !(n == 1 || n == 3) || segment.len() != 6 + 3 * n {
        return None;
    }
    let comps: Vec<FrameComponent> = segment[6..]
        .chunks_exact(3)
        .map(|c| FrameComponent {
            id: c[0],
            h: usize::from(c[1] >> 4),
            v: usize::from(c[1] & 15),
            tq: usize::from(c[2]),
        })
        .collect();
    let sane = |c: &FrameComponent| (1..=4).contains(&c.h) && (1..=4).contains(&c.v) && c.tq < 4;
    if !comps.iter().all(sane) {
        return None;
    }
    // The luma must have the largest sampling factors: its plane is then the picture's size.
    let (hmax, vmax) = (
        comps.iter().map(|c| c.h).max()?,
        comps.iter().map(|c| c.v).max()?,
    );
    if n == 3 && (comps[0].h != hmax || comps[0].v != vmax) {
        return None;
    }
    let ids_distinct = n == 1
        || (comps[0].id != comps[1].id && comps[0].id != comps[2].id && comps[1].id != comps[2].id);
    ids_distinct.then_some((width, height, comps))
}

/// SOS: a sequential scan (Ss 0, Se 63, no successive approximation) over every component of the
/// frame, each with defined tables; the luma first.
fn parse_sos(
    segment: &[u8],
    comps: &[FrameComponent],
    dc: &[Option<HuffTable>; 4],
    ac: &[Option<HuffTable>; 4],
) -> Option<Vec<Component>> {
    let n = usize::from(*segment.first()?);
    if n != comps.len() || segment.len() != 1 + 2 * n + 3 {
        return None;
    }
    let tail = &segment[1 + 2 * n..];
    if tail != [0, 63, 0] {
        return None;
    }
    let mut out = Vec::with_capacity(n);
    for (i, sel) in segment[1..1 + 2 * n].chunks_exact(2).enumerate() {
        // Scan order must be frame order (as the standard asks of an interleaved scan).
        let c = comps.get(i).filter(|c| c.id == sel[0])?;
        let (td, ta) = (usize::from(sel[1] >> 4), usize::from(sel[1] & 15));
        if td > 3 || ta > 3 || dc[td].is_none() || ac[ta].is_none() {
            return None;
        }
        let (h, v) = if n == 1 { (1, 1) } else { (c.h, c.v) };
        out.push(Component {
            h,
            v,
            dc: td,
            ac: ta,
        });
    }
    Some(out)
}
