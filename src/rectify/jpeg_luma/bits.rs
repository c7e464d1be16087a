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
    /// A code and its magnitude bits that fit in `FAST_BITS`, as an [`FastEntry`] (0 if they do
    /// not fit): in an AC table a coefficient and the symbol after it when that fits too, in a
    /// DC table the difference alone.
    fast_value: Box<[u64; FAST_SIZE]>,
}

/// One `fast_value` entry, packed in a `u64`: byte 0 the bits of the first value (code and
/// magnitude), byte 1 those of both symbols, byte 2 the first's run of zeros, byte 3 the second's
/// run (low 4 bits) with [`SECOND`](Self::SECOND) or [`SECOND_EOB`](Self::SECOND_EOB), then the
/// first value and the second as i16. Byte 1 equals byte 0 when only the first fits (always in
/// a DC table).
struct FastEntry;

impl FastEntry {
    /// The second symbol is a coefficient.
    const SECOND: u64 = 0x10 << 24;
    /// The second symbol is the end of the block.
    const SECOND_EOB: u64 = 0x20 << 24;

    /// `first` (bits, run, value), then what follows it in the window: a coefficient, the end
    /// of the block (`Err(Some(bits))`) or nothing that fits (`Err(None)`), as
    /// [`HuffTable::coefficient_at`] tells them.
    fn pack(first: (u32, u32, i32), next: Result<(u32, u32, i32), Option<u32>>) -> u64 {
        let (bits1, run1, value1) = first;
        let (both, run2, value2, flag) = match next {
            Ok((bits2, run2, value2)) => (bits1 + bits2, run2, value2, Self::SECOND),
            Err(Some(bits2)) => (bits1 + bits2, 0, 0, Self::SECOND_EOB),
            Err(None) => (bits1, 0, 0, 0),
        };
        u64::from(bits1)
            | u64::from(both) << 8
            | u64::from(run1) << 16
            | u64::from(run2) << 24
            | flag
            | u64::from(value1 as u16) << 32
            | u64::from(value2 as u16) << 48
    }
}

impl Default for HuffTable {
    fn default() -> Self {
        HuffTable {
            fast: Box::new([0; FAST_SIZE]),
            maxcode: [0; 18],
            delta: [0; 17],
            symbols: Vec::new(),
            fast_value: Box::new([0; FAST_SIZE]),
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
        } else {
            t.build_fast_dc();
        }
        Some(t)
    }

    /// The coefficient (bits, run, value) whose code starts the `FAST_BITS` window `i` when it
    /// and its magnitude bits fit within the window's first `room` bits; `Err(Some(bits))` for
    /// an end of block that fits, `Err(None)` otherwise.
    fn coefficient_at(&self, i: usize, room: u32) -> Result<(u32, u32, i32), Option<u32>> {
        let entry = self.fast[i];
        if entry == 0 {
            return Err(None);
        }
        let (len, sym) = (u32::from(entry >> 8), entry & 0xFF);
        let (run, size) = (u32::from(sym >> 4), u32::from(sym & 15));
        if len > room {
            return Err(None);
        }
        if size == 0 {
            // End of block, or a run of 16 zeros (left to the slow path).
            return Err((sym == 0).then_some(len));
        }
        if len + size > room {
            return Err(None);
        }
        Ok((len + size, run, value_at(i, len, size)))
    }

    fn build_fast_ac(&mut self) {
        for i in 0..FAST_SIZE {
            let Ok(first) = self.coefficient_at(i, FAST_BITS) else {
                continue;
            };
            // The window's bits after the first coefficient, left-aligned (zeros after them).
            let rest = (i << first.0) & (FAST_SIZE - 1);
            self.fast_value[i] =
                FastEntry::pack(first, self.coefficient_at(rest, FAST_BITS - first.0));
        }
    }

    fn build_fast_dc(&mut self) {
        for i in 0..FAST_SIZE {
            let entry = self.fast[i];
            let (len, size) = (u32::from(entry >> 8), u32::from(entry & 0xFF));
            // Differences wider than 11 bits are left to `dc_diff`'s check.
            if entry == 0 || size > 11 || len + size > FAST_BITS {
                continue;
            }
            self.fast_value[i] =
                FastEntry::pack((len + size, 0, value_at(i, len, size)), Err(None));
        }
    }
}

/// The signed value of the `size` magnitude bits that follow a code of `len` bits at the start
/// of the `FAST_BITS` window `i` (`len + size` ≤ `FAST_BITS`).
fn value_at(i: usize, len: u32, size: u32) -> i32 {
    let bits = (i as u32 >> (FAST_BITS - len - size)) & ((1 << size) - 1);
    extend(bits, size)
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

/// The symbol of `t` whose code, longer than `FAST_BITS`, starts `code16`, and its length.
#[inline(never)]
fn long_symbol(code16: u32, t: &HuffTable) -> Result<(u8, u32), DataError> {
    let mut len = FAST_BITS + 1;
    while code16 >= t.maxcode[len as usize] {
        len += 1;
    }
    if len > 16 {
        return Err(DataError::BadCode);
    }
    let code = (code16 >> (16 - len)) as i32;
    let index = usize::try_from(code + t.delta[len as usize]).map_err(|_| DataError::BadCode)?;
    let sym = *t.symbols.get(index).ok_or(DataError::BadCode)?;
    Ok((sym, len))
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
///
/// `Copy`, so that [`BitReader::block`] decodes on a copy in local variables: the compiler keeps
/// those in registers only if their address never escapes, which is why the slow paths take the
/// reader by value and return it.
#[derive(Clone, Copy)]
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
        *self = self.refilled_slow();
    }

    #[cold]
    #[inline(never)]
    fn refilled_slow(mut self) -> Self {
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
        self
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
        let (sym, len) = long_symbol(self.peek(16), t)?;
        self.consume(len);
        Ok(sym)
    }

    /// The DC difference of a block.
    #[inline(always)]
    pub(super) fn dc_diff(&mut self, t: &HuffTable) -> Result<i32, DataError> {
        self.refill();
        let fast = t.fast_value[self.peek(FAST_BITS) as usize];
        if fast != 0 {
            self.consume((fast & 0xFF) as u32);
            return Ok(i32::from((fast >> 32) as i16));
        }
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
        // On a copy in locals (registers), written back whatever the outcome.
        let mut reader = *self;
        let result = reader.block_in_locals::<KEEP>(dc, ac, pred, block);
        *self = reader;
        result
    }

    #[inline(always)]
    fn block_in_locals<const KEEP: bool>(
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
            let fast = ac.fast_value[self.peek(FAST_BITS) as usize];
            if fast != 0 {
                // The first coefficient; then the second symbol, when it fits in the window and
                // the block is not full (after its last coefficient comes the next block's DC).
                k += ((fast >> 16) & 0xFF) as usize;
                if KEEP {
                    block[usize::from(ZIGZAG[k & 127] & 63)] = (fast >> 32) as i16;
                }
                k += 1;
                if fast & (FastEntry::SECOND | FastEntry::SECOND_EOB) != 0 && k < 64 {
                    self.consume(((fast >> 8) & 0xFF) as u32);
                    if fast & FastEntry::SECOND_EOB != 0 {
                        break;
                    }
                    k += ((fast >> 24) & 0x0F) as usize;
                    if KEEP {
                        block[usize::from(ZIGZAG[k & 127] & 63)] = (fast >> 48) as i16;
                    }
                    k += 1;
                } else {
                    self.consume((fast & 0xFF) as u32);
                }
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
