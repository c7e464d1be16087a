//! Whether a progressive frame's first DC scan codes every block its frame header claims: the
//! marker walk ([`crate::rectify::jpeg_scan`]) asks, since zune-jpeg decodes the blocks a scan
//! never reaches as zero. A DC first scan codes each block's DC difference as a baseline scan
//! does (a Huffman code and its magnitude bits), so its codes are read here to the last MCU with
//! the baseline decoder's reader, and dropped.

use super::bits::{BitReader, HuffTable};

/// A component of a DC scan: its sampling factors (h, v) and its DC table's DHT counts and
/// symbols.
pub(in crate::rectify) type DcComponent<'a> = ((usize, usize), &'a [u8; 16], &'a [u8]);

/// A progressive frame's DC first scan (Ss = Se = 0, Ah = 0), as the marker walk found it.
pub(in crate::rectify) struct DcScan<'a> {
    /// The frame's size in pixels.
    pub(in crate::rectify) width: usize,
    pub(in crate::rectify) height: usize,
    /// The largest sampling factors of the frame's components.
    pub(in crate::rectify) max_hv: (usize, usize),
    /// The scan's components, in scan order.
    pub(in crate::rectify) components: Vec<DcComponent<'a>>,
    /// MCUs between restart markers (0: none).
    pub(in crate::rectify) restart_interval: usize,
    /// Where the scan's entropy-coded data starts.
    pub(in crate::rectify) data_start: usize,
}

/// Whether the scan's codes reach its last MCU before its data ends (or meets a marker other
/// than the next restart marker); false too for a bit sequence that is no code, a table that is
/// no prefix code, or a scan whose size cannot be computed.
pub(in crate::rectify) fn dc_scan_complete(bytes: &[u8], scan: &DcScan) -> bool {
    let (hmax, vmax) = scan.max_hv;
    if hmax == 0 || vmax == 0 || scan.components.is_empty() {
        return false;
    }
    let mut tables = Vec::with_capacity(scan.components.len());
    for &(_, counts, symbols) in &scan.components {
        match HuffTable::new(counts, symbols, false) {
            Some(t) => tables.push(t),
            None => return false,
        }
    }
    // Blocks of each component per MCU, and MCUs (T.81 A.2: a scan of one component is not
    // interleaved: one block an MCU, over that component's own blocks).
    let (mcus, per_mcu): (usize, Vec<usize>) = match scan.components.as_slice() {
        [((h, v), _, _)] => {
            let w = (scan.width * h).div_ceil(hmax).div_ceil(8);
            let hgt = (scan.height * v).div_ceil(vmax).div_ceil(8);
            (w * hgt, vec![1])
        }
        many => (
            scan.width.div_ceil(8 * hmax) * scan.height.div_ceil(8 * vmax),
            many.iter().map(|((h, v), _, _)| h * v).collect(),
        ),
    };
    let mut reader = BitReader::new(bytes, scan.data_start);
    let mut restarts = 0u8;
    for mcu in 0..mcus {
        if scan.restart_interval > 0 && mcu > 0 && mcu % scan.restart_interval == 0 {
            if reader.overran() || reader.restart(restarts).is_err() {
                return false;
            }
            restarts = restarts.wrapping_add(1);
        }
        for (table, &n) in tables.iter().zip(&per_mcu) {
            for _ in 0..n {
                if reader.dc_diff(table).is_err() {
                    return false;
                }
            }
        }
        // Once the data has run out only zero bits follow, and they may well be codes: stop.
        if reader.overran() {
            return false;
        }
    }
    true
}
