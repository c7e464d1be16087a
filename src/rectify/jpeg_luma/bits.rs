//! The entropy-coded data: a 64-bit bit reader and Huffman decoding with lookup tables.
//!
//! The reader refills eight bytes at a time when none of them is 0xFF (the common case); the slow
//! path undoes byte stuffing (0xFF 0x00) and stops at a marker, after which (as after the end of
//! the data) it feeds zero bits and counts them, so that a scan that reads into them is known to
//! be cut short.

use super::zigzag::ZIGZAG;

/// Bits looked up at once.
const FAST_BITS: u32 = 12;
const FAST_SIZE: usize = 1 << FAST_BITS;

/// A Huffman table: a `FAST_BITS` lookup for short codes, the canonical code bounds for the
/// rest, and for AC tables the fused lookup of a short code with its magnitude bits.
#[derive(Clone)]
pub(crate) struct HuffTable {
    /// `length << 8 | symbol` of the code starting with the index's bits; 0 if longer.
    fast: Box<[u16; FAST_SIZE]>,
    /// Per code length l: the first code of length l+1, left-aligned to 16 bits (exclusive upper
    /// bound of codes of length l); index 17 is a sentinel.
    maxcode: [u32; 18],
    /// Per code length: symbol index minus code.
    delta: [i32; 17],
    symbols: Vec<u8>,
    /// AC only: `value << 16 | run << 8 | total bits` for a code and its magnitude bits that fit in
    /// `FAST_BITS` (0 if not).
    fast_ac: Box<[i32; FAST_SIZE]>,
}

impl Default for HuffTable {
    fn default() -> Self {
        HuffTable {
            fast: Box::new([0; FAST_SIZE]),
            maxcode: [0; 18],
            delta: [0; 17],
            symbols: Vec::new(),
            fast_ac: Box::new([0; FAST_SIZE]),
        }
    }
}

impl HuffTable {
    /// The table of a DHT segment (`counts` of codes per length 1..=16, `symbols` in code order);
    /// `None` if the counts describe no prefix code.
    pub(super) fn new(counts: &[u8; 16], symbols: &[u8], ac: bool) -> Option<HuffTable> {
        let mut t = HuffTable {
            symbols: symbols.to_vec(),
            ..HuffTable::default()
        };
        let mut code: u32 = 0;
        let mut k: usize = 0;
        for len in 1..=16u32 {
            let n = u32::from(counts[len as usize - 1]);
            t.delta[len as usize] = k as i32 - code as i32;
            for _ in 0..n {
                if code >= 1 << len {
                    return None;
                }
                if len <= FAST_BITS {
                    let shift = FAST_BITS - len;
                    let entry = (len as u16) << 8 | u16::from(symbols[k]);
                    for i in (code << shift)..((code + 1) << shift) {
                        t.fast[i as usize] = entry;
                    }
                }
                code += 1;
                k += 1;
            }
            // A code of all ones at its length is not allowed (as libjpeg has it).
            if code >= 1 << len {
                return None;
            }
            t.maxcode[len as usize] = code << (16 - len);
            code <<= 1;
        }
        t.maxcode[17] = u32::MAX;
        if ac {
            t.build_fast_ac();
        }
        Some(t)
    }

    fn build_fast_ac(&mut self) {
        for i in 0..FAST_SIZE {
            let entry = self.fast[i];
            if entry == 0 {
                continue;
            }
            let (len, sym) = (u32::from(entry >> 8), entry & 0xFF);
            let (run, size) = (u32::from(sym >> 4), u32::from(sym & 15));
            if size == 0 || len + size > FAST_BITS {
                continue;
            }
            let bits = (i as u32 >> (FAST_BITS - len - size)) & ((1 << size) - 1);
            let value = extend(bits, size);
            self.fast_ac[i] = value << 16 | (run << 8) as i32 | (len + size) as i32;
        }
    }
}

/// The signed value of `size` magnitude bits.
#[inline(always)]
fn extend(bits: u32, size: u32) -> i32 {
    if size == 0 {
        0
    } else if bits < 1 << (size - 1) {
        bits as i32 - (1 << size) + 1
    } else {
        bits as i32
    }
}

/// Why the entropy-coded data could not be decoded.
#[derive(Debug, PartialEq, Eq)]
pub(super) enum DataError {
    /// A bit sequence that is no code of the table.
    BadCode,
    /// A DC difference wider than 11 bits.
    BadDc,
}

/// The bit reader over one scan's entropy-coded data (and what follows it).
pub(super) struct BitReader<'a> {
    data: &'a [u8],
    /// The next byte not in `buf`.
    pos: usize,
    /// Bits, left-aligned; below the `nbits` valid ones there may be copies of the bytes at `pos`
    /// (never anything else), which the next refill ORs in again.
    buf: u64,
    nbits: u32,
    /// A marker (or the end of the data) was reached: only zero bits follow.
    stopped: bool,
    /// Zero bits fed after the marker or end.
    pad_bits: u32,
}

impl<'a> BitReader<'a> {
    pub(super) fn new(data: &'a [u8], pos: usize) -> Self {
        BitReader {
            data,
            pos,
            buf: 0,
            nbits: 0,
            stopped: false,
            pad_bits: 0,
        }
    }

    /// At least 32 valid bits in `buf` afterwards (56 or more).
    #[inline(always)]
    fn refill(&mut self) {
        if self.nbits >= 32 {
            return;
        }
        if let Some(bytes) = self.data.get(self.pos..self.pos + 8) {
            let word = u64::from_be_bytes(bytes.try_into().unwrap_or([0xFF; 8]));
            // No byte is 0xFF: no byte of !word is zero.
            let inv = !word;
            if (inv.wrapping_sub(0x0101_0101_0101_0101) & !inv & 0x8080_8080_8080_8080) == 0 {
                self.buf |= word >> self.nbits;
                self.pos += ((63 - self.nbits) >> 3) as usize;
                self.nbits |= 56;
                return;
            }
        }
        self.refill_slow();
    }

    #[cold]
    #[inline(never)]
    fn refill_slow(&mut self) {
        // Drop the copies below the valid bits: the bytes come one by one now.
        self.buf &= if self.nbits == 0 {
            0
        } else {
            !0u64 << (64 - self.nbits)
        };
        while self.nbits <= 56 {
            let byte = if self.stopped {
                self.pad_bits += 8;
                0
            } else {
                match self.data.get(self.pos) {
                    Some(&0xFF) if self.data.get(self.pos + 1) == Some(&0) => {
                        self.pos += 2;
                        0xFF
                    }
                    Some(&0xFF) | None => {
                        // A marker (left for `restart`), or the end of the data.
                        self.stopped = true;
                        continue;
                    }
                    Some(&b) => {
                        self.pos += 1;
                        b
                    }
                }
            };
            self.buf |= u64::from(byte) << (56 - self.nbits);
            self.nbits += 8;
        }
    }

    /// Whether the decoding has read into the zero bits that follow a marker or the end.
    pub(super) fn overran(&self) -> bool {
        self.pad_bits > self.nbits
    }

    #[inline(always)]
    fn peek(&self, n: u32) -> u32 {
        (self.buf >> (64 - n)) as u32
    }

    #[inline(always)]
    fn consume(&mut self, n: u32) {
        self.buf <<= n;
        self.nbits -= n;
    }

    /// `size` (1..=15) magnitude bits, extended to their signed value.
    #[inline(always)]
    fn receive_extend(&mut self, size: u32) -> i32 {
        let bits = self.peek(size);
        self.consume(size);
        extend(bits, size)
    }

    /// The next symbol of `t` (the caller has refilled).
    #[inline(always)]
    fn symbol(&mut self, t: &HuffTable) -> Result<u8, DataError> {
        let entry = t.fast[self.peek(FAST_BITS) as usize];
        if entry != 0 {
            self.consume(u32::from(entry >> 8));
            return Ok(entry as u8);
        }
        self.symbol_slow(t)
    }

    #[inline(never)]
    fn symbol_slow(&mut self, t: &HuffTable) -> Result<u8, DataError> {
        let code16 = self.peek(16);
        let mut len = FAST_BITS + 1;
        while code16 >= t.maxcode[len as usize] {
            len += 1;
        }
        if len > 16 {
            return Err(DataError::BadCode);
        }
        let code = (code16 >> (16 - len)) as i32;
        let index =
            usize::try_from(code + t.delta[len as usize]).map_err(|_| DataError::BadCode)?;
        let sym = *t.symbols.get(index).ok_or(DataError::BadCode)?;
        self.consume(len);
        Ok(sym)
    }

    /// The DC difference of a block.
    #[inline(always)]
    fn dc_diff(&mut self, t: &HuffTable) -> Result<i32, DataError> {
        self.refill();
        let size = u32::from(self.symbol(t)?);
        if size > 11 {
            return Err(DataError::BadDc);
        }
        Ok(if size == 0 {
            0
        } else {
            self.receive_extend(size)
        })
    }

    /// One block's coefficients into `block` (natural order, zero on entry) if `KEEP`, else
    /// decoded and dropped (a chroma block); its DC predicted from `pred` either way.
    #[inline(always)]
    pub(super) fn block<const KEEP: bool>(
        &mut self,
        dc: &HuffTable,
        ac: &HuffTable,
        pred: &mut i32,
        block: &mut [i16; 64],
    ) -> Result<(), DataError> {
        *pred = (*pred + self.dc_diff(dc)?).clamp(-2047, 2047);
        if KEEP {
            block[0] = *pred as i16;
        }
        let mut k = 1usize;
        while k < 64 {
            self.refill();
            let fast = ac.fast_ac[self.peek(FAST_BITS) as usize];
            if fast != 0 {
                k += ((fast >> 8) & 0xFF) as usize;
                self.consume((fast & 0xFF) as u32);
                if KEEP {
                    block[usize::from(ZIGZAG[k & 127] & 63)] = (fast >> 16) as i16;
                }
                k += 1;
                continue;
            }
            let sym = self.symbol(ac)?;
            let (run, size) = (usize::from(sym >> 4), u32::from(sym & 15));
            if size == 0 {
                if run != 15 {
                    break;
                }
                k += 16;
                continue;
            }
            k += run;
            if KEEP {
                let value = self.receive_extend(size);
                block[usize::from(ZIGZAG[k & 127] & 63)] = value as i16;
            } else {
                self.consume(size);
            }
            k += 1;
        }
        Ok(())
    }

    /// Moves past the restart marker that must come next (`RST0 + index`); `Err(true)` if another
    /// marker or the end of the data comes instead (a cut file), `Err(false)` for a restart marker
    /// out of sequence.
    pub(super) fn restart(&mut self, index: u8) -> Result<(), bool> {
        self.buf = 0;
        self.nbits = 0;
        self.pad_bits = 0;
        self.stopped = false;
        // Bytes left before the marker (an encoder's stray padding) are skipped.
        let mut pos = self.pos;
        loop {
            let at = pos
                + self
                    .data
                    .get(pos..)
                    .and_then(|d| d.iter().position(|&b| b == 0xFF))
                    .ok_or(true)?;
            let mut next = at + 1;
            while self.data.get(next) == Some(&0xFF) {
                next += 1;
            }
            match self.data.get(next) {
                Some(0) => pos = next + 1,
                Some(&m) if m == 0xD0 + (index & 7) => {
                    self.pos = next + 1;
                    return Ok(());
                }
                Some(0xD0..=0xD7) => return Err(false),
                _ => return Err(true),
            }
        }
    }
}
