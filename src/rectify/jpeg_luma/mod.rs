//! Our own decoder of a JPEG's luma for the common case: a baseline or extended sequential 8-bit
//! frame, grey or three components in one interleaved scan (any sampling factors, the luma's
//! the largest), restart intervals or none. Every other JPEG goes to zune-jpeg (`decode.rs`).
//!
//! Only the luma blocks are kept: chroma blocks are Huffman-decoded (the data is sequential, so
//! they must be read) and dropped. With two cores or more the Huffman decoding (this thread) and
//! the dequantisation and IDCT (a second thread) run side by side on bands of a few MCU rows, a
//! small fixed number of bands in flight.
//!
//! Given the rectifier the luma is for, only the blocks it can read ([`super::footprint`]) are
//! kept and IDCT'd; the others are Huffman-decoded and dropped, and their pixels stay 0.
//!
//! Entropy-coded data that ends, or meets a marker other than the next restart marker, before the
//! last MCU is an error (the file was cut short), as is a bit sequence that is no Huffman code.

mod bits;
mod dc_scan;
mod header;
mod idct;
#[cfg(target_arch = "x86_64")]
mod idct_avx2;
mod zigzag;

use std::ops::Range;

use image::GrayImage;

use super::{Rectifier, RectifyError};
use bits::{BitReader, DataError, HuffTable};
use header::{Component, Header};
use idct::Band;

pub(in crate::rectify) use dc_scan::{dc_scan_complete, DcScan};

/// MCU rows per band, and bands in flight between the two threads.
const BAND_MCU_ROWS: usize = 4;
const BANDS_IN_FLIGHT: usize = 4;

/// The luma of `bytes`, or `None` if the frame is not one this decoder handles. With `for_`,
/// only the pixels that rectifier reads are decoded (the others are 0).
pub(super) fn decode_luma(
    bytes: &[u8],
    for_: Option<&Rectifier>,
) -> Option<Result<GrayImage, RectifyError>> {
    let header = header::parse(bytes)?;
    Some(decode(bytes, &header, threaded(), for_))
}

/// Whether to run the IDCT on a second thread.
fn threaded() -> bool {
    std::thread::available_parallelism().is_ok_and(|n| n.get() > 1)
}

/// The MCU layout of the scan.
struct Layout {
    mcus_x: usize,
    mcus_y: usize,
    /// Luma blocks per MCU across and down.
    luma_h: usize,
    luma_v: usize,
}

impl Layout {
    fn new(h: &Header) -> Layout {
        let (hmax, vmax) = if h.components.len() == 1 {
            (1, 1)
        } else {
            (
                h.components.iter().map(|c| c.h).max().unwrap_or(1),
                h.components.iter().map(|c| c.v).max().unwrap_or(1),
            )
        };
        Layout {
            mcus_x: h.width.div_ceil(8 * hmax),
            mcus_y: h.height.div_ceil(8 * vmax),
            luma_h: h.components[0].h,
            luma_v: h.components[0].v,
        }
    }

    fn blocks_per_row(&self) -> usize {
        self.mcus_x * self.luma_h
    }

    /// Coefficients of one band (`BAND_MCU_ROWS` MCU rows of luma blocks).
    fn band_len(&self) -> usize {
        BAND_MCU_ROWS * self.luma_v * self.blocks_per_row() * 64
    }

    /// Pixel rows per band.
    fn band_rows(&self) -> usize {
        BAND_MCU_ROWS * self.luma_v * 8
    }

    /// Luma block rows per band.
    fn band_block_rows(&self) -> usize {
        BAND_MCU_ROWS * self.luma_v
    }

    /// Per luma block row of the frame, the block columns `rectifier` reads of a frame of `h`.
    fn needed(&self, h: &Header, rectifier: &Rectifier) -> Option<Vec<Range<usize>>> {
        let footprint = rectifier.footprint(h.width, h.height)?;
        let per_row = self.blocks_per_row();
        Some(
            (0..self.mcus_y * self.luma_v)
                .map(|br| match footprint.columns_of(br * 8..br * 8 + 8) {
                    Some((a, b)) => (a as usize / 8)..(b as usize / 8 + 1).min(per_row),
                    None => 0..0,
                })
                .collect(),
        )
    }
}

fn decode(
    bytes: &[u8],
    h: &Header,
    threaded: bool,
    for_: Option<&Rectifier>,
) -> Result<GrayImage, RectifyError> {
    let kept = for_.and_then(|_| super::reuse::take(h.width * h.height));
    decode_into(bytes, h, threaded, for_, kept)
}

/// [`decode`] into `kept`, a buffer of the frame's size holding anything, when there is one.
fn decode_into(
    bytes: &[u8],
    h: &Header,
    threaded: bool,
    for_: Option<&Rectifier>,
    kept: Option<Vec<u8>>,
) -> Result<GrayImage, RectifyError> {
    super::check_frame_size(h.width as u64, h.height as u64)?;
    let layout = Layout::new(h);
    let needed = for_.and_then(|r| layout.needed(h, r));
    let needed = needed.as_deref();
    let quant: [i32; 64] = h.luma_quant.map(i32::from);
    // With a rectifier, the buffer of a frame before when one is kept (`reuse.rs`): its pixels
    // outside the needed blocks are zeroed band by band. Otherwise fresh zeroed pages (a frame is
    // above glibc's largest mmap threshold): the blocks left out are never touched, and huge
    // pages spare the rest ~9,000 first-touch faults (8% of the decode of a D810 frame,
    // measured).
    let len = h.width * h.height;
    let kept = kept.filter(|k| k.len() == len && needed.is_some());
    let (mut pixels, stale) = match kept {
        Some(kept) => (kept, true),
        None => {
            let mut fresh = vec![0u8; len];
            super::os::advise_huge_pages(&mut fresh);
            (fresh, false)
        }
    };
    let bands = layout.mcus_y.div_ceil(BAND_MCU_ROWS);
    let band_bytes = layout.band_rows() * h.width;
    let mut scan = Scan::new(bytes, h, needed)?;
    let job = Pixels {
        layout: &layout,
        width: h.width,
        quant: &quant,
        needed,
        stale,
    };
    if !threaded || bands < 3 {
        let mut coefs = vec![0i16; layout.band_len()];
        for (band, out) in pixels.chunks_mut(band_bytes).enumerate() {
            scan.band(&layout, band, &mut coefs)?;
            job.band(band, &mut coefs, out);
        }
    } else {
        pipelined(&mut scan, &job, &mut pixels, band_bytes)?;
    }
    scan.finish()?;
    GrayImage::from_raw(h.width as u32, h.height as u32, pixels)
        .ok_or_else(|| RectifyError::Jpeg("decoder returned a wrong-sized buffer".into()))
}

/// What turns a band's coefficients into pixels.
struct Pixels<'a> {
    layout: &'a Layout,
    width: usize,
    quant: &'a [i32; 64],
    /// Per luma block row of the frame, the block columns to transform (all if `None`).
    needed: Option<&'a [Range<usize>]>,
    /// The pixels hold a frame before's, to be zeroed outside the needed blocks.
    stale: bool,
}

impl Pixels<'_> {
    /// Dequantises and IDCTs band `band` (its needed blocks only), on AVX2 when the CPU has it.
    fn band(&self, band: usize, coefs: &mut [i16], out: &mut [u8]) {
        let rows = self.layout.band_block_rows();
        let needed = self
            .needed
            .map(|all| &all[(band * rows).min(all.len())..((band + 1) * rows).min(all.len())]);
        if let Some(needed) = needed.filter(|_| self.stale) {
            zero_unneeded(out, self.width, needed);
        }
        let band = Band {
            coefs,
            blocks_per_row: self.layout.blocks_per_row(),
            out,
            width: self.width,
            needed,
        };
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above).
            unsafe { idct_avx2::band(band, self.quant) };
            return;
        }
        idct::band(band, self.quant);
    }
}

/// Zeroes the pixels of `out` (a band's rows of `width`) outside the block columns `needed` lists
/// for each of its block rows (rows past the list: all of them).
fn zero_unneeded(out: &mut [u8], width: usize, needed: &[Range<usize>]) {
    if width == 0 {
        return;
    }
    for (y, row) in out.chunks_mut(width).enumerate() {
        let columns = needed.get(y / 8).cloned().unwrap_or(0..0);
        let (a, b) = ((columns.start * 8).min(width), (columns.end * 8).min(width));
        if a >= b {
            row.fill(0);
        } else {
            row[..a].fill(0);
            row[b..].fill(0);
        }
    }
}

/// Huffman decoding on this thread, IDCT on another; bands go there full and come back zeroed.
fn pipelined(
    scan: &mut Scan<'_>,
    job: &Pixels<'_>,
    pixels: &mut [u8],
    band_bytes: usize,
) -> Result<(), RectifyError> {
    let layout = job.layout;
    let (full_tx, full_rx) = crossbeam_channel::bounded::<Vec<i16>>(BANDS_IN_FLIGHT);
    let (free_tx, free_rx) = crossbeam_channel::bounded::<Vec<i16>>(BANDS_IN_FLIGHT);
    for _ in 0..BANDS_IN_FLIGHT {
        // The channel has room for every band.
        let _ = free_tx.send(vec![0i16; layout.band_len()]);
    }
    std::thread::scope(|s| {
        s.spawn(move || {
            // Bands come in order, one for each chunk of rows.
            let bands = full_rx.into_iter().zip(pixels.chunks_mut(band_bytes));
            for (band, (mut coefs, out)) in bands.enumerate() {
                job.band(band, &mut coefs, out);
                if free_tx.send(coefs).is_err() {
                    break;
                }
            }
        });
        let bands = layout.mcus_y.div_ceil(BAND_MCU_ROWS);
        for band in 0..bands {
            let stopped = || RectifyError::Jpeg("the IDCT thread stopped".into());
            let mut coefs = free_rx.recv().map_err(|_| stopped())?;
            scan.band(layout, band, &mut coefs)?;
            full_tx.send(coefs).map_err(|_| stopped())?;
        }
        drop(full_tx);
        Ok(())
    })
}

/// The state of the scan's Huffman decoding.
struct Scan<'a> {
    reader: BitReader<'a>,
    components: Vec<(Component, &'a HuffTable, &'a HuffTable)>,
    preds: [i32; 3],
    restart_interval: usize,
    /// Per luma block row, the block columns kept (all if `None`).
    needed: Option<&'a [Range<usize>]>,
    /// MCUs decoded so far, and restart markers passed.
    mcus: usize,
    restarts: usize,
    total_mcus: usize,
}

impl<'a> Scan<'a> {
    fn new(
        bytes: &'a [u8],
        h: &'a Header,
        needed: Option<&'a [Range<usize>]>,
    ) -> Result<Scan<'a>, RectifyError> {
        let components = h
            .components
            .iter()
            .map(|c| {
                // parse_sos checked both tables are defined.
                match (&h.dc_tables[c.dc], &h.ac_tables[c.ac]) {
                    (Some(dc), Some(ac)) => Ok((*c, dc, ac)),
                    _ => Err(RectifyError::Jpeg(
                        "a scan uses an undefined Huffman table".into(),
                    )),
                }
            })
            .collect::<Result<_, _>>()?;
        let layout = Layout::new(h);
        Ok(Scan {
            reader: BitReader::new(bytes, h.data_start),
            components,
            preds: [0; 3],
            restart_interval: h.restart_interval,
            needed,
            mcus: 0,
            restarts: 0,
            total_mcus: layout.mcus_x * layout.mcus_y,
        })
    }

    /// The MCU rows of band `band` into `coefs` (zero on entry).
    fn band(
        &mut self,
        layout: &Layout,
        band: usize,
        coefs: &mut [i16],
    ) -> Result<(), RectifyError> {
        let first = band * BAND_MCU_ROWS;
        let last = (first + BAND_MCU_ROWS).min(layout.mcus_y);
        let per_row = layout.blocks_per_row();
        for (i, mcu_row) in (first..last).enumerate() {
            for mx in 0..layout.mcus_x {
                if self.restart_interval > 0
                    && self.mcus > 0
                    && self.mcus.is_multiple_of(self.restart_interval)
                {
                    self.restart()?;
                }
                let rows = (i * layout.luma_v, mcu_row * layout.luma_v);
                self.mcu(layout, coefs, rows, per_row, mx).map_err(|e| {
                    // Zero bits after the end that are no code are the end's fault.
                    if self.reader.overran() {
                        cut_short()
                    } else {
                        data_error(e)
                    }
                })?;
                self.mcus += 1;
            }
            if self.reader.overran() {
                return Err(cut_short());
            }
        }
        Ok(())
    }

    /// One MCU; its luma blocks start at block row `rows.0` of the band, `rows.1` of the frame.
    #[inline(always)]
    fn mcu(
        &mut self,
        layout: &Layout,
        coefs: &mut [i16],
        rows: (usize, usize),
        per_row: usize,
        mx: usize,
    ) -> Result<(), DataError> {
        let (block_row, frame_row) = rows;
        let (luma, dc, ac) = self.components[0];
        for by in 0..luma.v {
            for bx in 0..luma.h {
                let column = mx * layout.luma_h + bx;
                if let Some(needed) = self.needed {
                    if !needed
                        .get(frame_row + by)
                        .is_some_and(|n| n.contains(&column))
                    {
                        // Never written: a block the rectifier does not read.
                        let mut unused = [0i16; 64];
                        self.reader
                            .block::<false>(dc, ac, &mut self.preds[0], &mut unused)?;
                        continue;
                    }
                }
                let index = (block_row + by) * per_row + column;
                let Some(block) = coefs
                    .get_mut(index * 64..index * 64 + 64)
                    .and_then(|b| <&mut [i16; 64]>::try_from(b).ok())
                else {
                    return Err(DataError::BadCode);
                };
                self.reader
                    .block::<true>(dc, ac, &mut self.preds[0], block)?;
            }
        }
        for c in 1..self.components.len() {
            let (comp, dc, ac) = self.components[c];
            for _ in 0..comp.h * comp.v {
                // Never written: chroma coefficients are dropped.
                let mut unused = [0i16; 64];
                self.reader
                    .block::<false>(dc, ac, &mut self.preds[c], &mut unused)?;
            }
        }
        Ok(())
    }

    fn restart(&mut self) -> Result<(), RectifyError> {
        if self.reader.overran() {
            return Err(cut_short());
        }
        match self.reader.restart(self.restarts as u8) {
            Ok(()) => {}
            Err(true) => return Err(cut_short()),
            Err(false) => {
                return Err(RectifyError::Jpeg(
                    "a restart marker out of sequence: the entropy-coded data is corrupt".into(),
                ))
            }
        }
        self.restarts += 1;
        self.preds = [0; 3];
        Ok(())
    }

    /// Checks that the last MCU was decoded from the data itself.
    fn finish(&self) -> Result<(), RectifyError> {
        if self.mcus != self.total_mcus || self.reader.overran() {
            return Err(cut_short());
        }
        Ok(())
    }
}

fn cut_short() -> RectifyError {
    RectifyError::Jpeg(
        "the entropy-coded data ends before the last MCU: the file was cut short (an interrupted \
         transfer or a full disk); take the frame again"
            .into(),
    )
}

fn data_error(e: DataError) -> RectifyError {
    RectifyError::Jpeg(
        match e {
            DataError::BadCode => {
                "a bit sequence that is no Huffman code: the entropy-coded data is corrupt"
            }
            DataError::BadDc => {
                "a DC difference wider than 11 bits: the entropy-coded data is corrupt"
            }
        }
        .into(),
    )
}

#[cfg(test)]
mod tests;
