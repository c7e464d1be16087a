//! Deflate (RFC 1951) of a slice's pixel data, fast: the samples, 16-bit little endian, coded as
//! literals with one dynamic Huffman code per segment, plus runs of a repeated sample as matches
//! at distance 2 (a sample is two bytes). No other string matching: on rectified camera frames
//! matches beyond runs are rare, and the literal codes are what makes the file small (on a
//! rectified D810 frame 13% larger than zlib's level 1 and 8% smaller than the miniz level 1
//! used before, in 0.07-0.08 of zlib level 1's time on two cores; benches/peers/deflate_vs_zlib.py,
//! docs/benchmarks.md). 8-bit samples (the luma of JPEG frames, stored in 16 bits) are coded
//! as one table entry per sample: the low byte's code followed by the high (zero) byte's.
//! Each segment is read twice: once to count the byte values of a quarter of it, spread evenly
//! (a plain histogram, no run scan: [`Segment::frequencies`]), once to write its tokens, finding
//! where runs start 16 samples at a time ([`scan`]); the codes go to the bit writer four at a
//! time ([`huffman::BitWriter::put_all`]).
//!
//! Segments of [`SEGMENT`] samples are coded in parallel, a few at a time in order
//! ([`deflate_samples_each`]: the file takes each group as it is done), each ending on a byte
//! boundary with an empty stored block (as zlib's sync flush and pigz do), so their
//! concatenation is one stream; the last one ends the stream.

mod huffman;

use huffman::{canonical_codes, code_lengths, reverse, write_dynamic_header, BitWriter};
use rayon::prelude::*;

/// Samples per segment (2 MiB of pixel data): one dynamic block each.
pub(crate) const SEGMENT: usize = 1 << 20;

/// A slice's samples as the frame path holds them.
#[derive(Clone, Copy, Debug)]
pub enum Samples<'a> {
    /// 8-bit values, stored as 16-bit samples (high byte 0).
    Gray8(&'a [u8]),
    /// 16-bit samples.
    Gray16(&'a [u16]),
}

impl Samples<'_> {
    pub fn len(&self) -> usize {
        match self {
            Samples::Gray8(s) => s.len(),
            Samples::Gray16(s) => s.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Samples `range` as 16-bit little-endian bytes, appended to `out`.
    pub(crate) fn extend_le(&self, range: std::ops::Range<usize>, out: &mut Vec<u8>) {
        match self {
            Samples::Gray8(s) => out.extend(s[range].iter().flat_map(|&v| [v, 0])),
            Samples::Gray16(s) => out.extend(s[range].iter().flat_map(|v| v.to_le_bytes())),
        }
    }

    fn slice(&self, range: std::ops::Range<usize>) -> Self {
        match self {
            Samples::Gray8(s) => Samples::Gray8(&s[range]),
            Samples::Gray16(s) => Samples::Gray16(&s[range]),
        }
    }
}

impl<'a> From<&'a [u16]> for Samples<'a> {
    fn from(s: &'a [u16]) -> Self {
        Samples::Gray16(s)
    }
}

impl<'a> From<&'a Vec<u16>> for Samples<'a> {
    fn from(s: &'a Vec<u16>) -> Self {
        Samples::Gray16(s)
    }
}

/// The samples deflated, as the parts of a raw deflate stream (each byte-aligned; an already
/// compressed, byte-aligned, non-final part may come before them); the last part ends the
/// stream. The tests' way to [`deflate_samples_each`]'s parts all at once.
#[cfg(test)]
pub(crate) fn deflate_samples(samples: Samples<'_>) -> Vec<Vec<u8>> {
    let mut all = Vec::new();
    let group = samples.len().div_ceil(SEGMENT).max(1);
    let _ = deflate_samples_each(samples, group, |parts| {
        all.extend(parts);
        Ok::<(), std::convert::Infallible>(())
    });
    all
}

/// The samples deflated, as the parts of a raw deflate stream (each byte-aligned; an already
/// compressed, byte-aligned, non-final part may come before them; the last part ends the
/// stream), handed to `each` in order `group` segments at a time as soon as those are coded
/// (each group's segments in parallel): a file takes each group before the next is coded, so
/// that the system can start writing it back meanwhile and only a group is held at a time.
/// Stops at the first error of `each`.
pub(crate) fn deflate_samples_each<E>(
    samples: Samples<'_>,
    group: usize,
    mut each: impl FnMut(Vec<Vec<u8>>) -> Result<(), E>,
) -> Result<(), E> {
    let n = samples.len();
    let segments = n.div_ceil(SEGMENT).max(1);
    let group = group.max(1);
    for first in (0..segments).step_by(group) {
        let parts = (first..(first + group).min(segments))
            .into_par_iter()
            .map(|k| {
                let range = k * SEGMENT..((k + 1) * SEGMENT).min(n);
                let last = k + 1 == segments;
                Segment::new(samples.slice(range)).encode(last)
            })
            .collect();
        each(parts)?;
    }
    Ok(())
}

/// Literal/length codes (0..=285), EOB at 256.
const LITLEN: usize = 286;
const EOB: usize = 256;
/// Longest run coded as one match: 129 samples (258 bytes).
const MAX_RUN: usize = 129;
/// The distance code of distance 2 (code 1, no extra bits); codes 0 and 1 both get 1 bit.
const DIST_CODE: u32 = 1;

/// Length code (257..=285) and its extra bits for a match of `len` bytes (3..=258).
fn length_code(len: usize) -> (usize, u32, u32) {
    const BASE: [u16; 29] = [
        3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115,
        131, 163, 195, 227, 258,
    ];
    const EXTRA: [u8; 29] = [
        0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0,
    ];
    let i = BASE.partition_point(|&b| usize::from(b) <= len) - 1;
    (
        257 + i,
        u32::from(EXTRA[i]),
        (len - usize::from(BASE[i])) as u32,
    )
}

/// One segment's samples and what its block is made of.
struct Segment<'a> {
    samples: Samples<'a>,
}

/// The sample types a segment's scan is compiled for.
trait Sample: Copy + PartialEq + Into<u16> {
    /// Whether a sample's high byte can be other than 0 (16-bit samples).
    const WIDE: bool;
    /// Samples one [`Sample::run_starts`] check covers.
    const CHUNK: usize;
    /// Where runs start in `s[i..i + CHUNK]`: bit `p` is set when `s[i + p] == s[i + p + 1] ==
    /// s[i + p + 2]`. Needs `i + CHUNK + 2 <= s.len()`.
    fn run_starts(s: &[Self], i: usize) -> u32;
}

/// The portable check: every window of three.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn run_starts_scalar<T: PartialEq>(s: &[T], i: usize, chunk: usize) -> u32 {
    s[i..i + chunk + 2]
        .windows(3)
        .enumerate()
        .filter(|(_, t)| t[0] == t[1] && t[1] == t[2])
        .fold(0, |m, (p, _)| m | 1 << p)
}

/// [`Sample::run_starts`] in SSE2 (part of every x86_64 target): three unaligned 16-byte loads
/// at samples 0, 1 and 2, compared for equal neighbours, 8-bit or (`WIDE`) 16-bit, a bit per
/// sample.
///
/// # Safety
/// `p` must be readable for 16 bytes plus two samples.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn sse2_run_starts<const WIDE: bool>(p: *const u8) -> u32 {
    use std::arch::x86_64::{
        __m128i, _mm_and_si128, _mm_cmpeq_epi16, _mm_cmpeq_epi8, _mm_loadu_si128,
        _mm_movemask_epi8, _mm_packs_epi16, _mm_setzero_si128,
    };
    let step = if WIDE { 2 } else { 1 };
    // SAFETY: the caller's promise covers the three loads.
    let (a, b, c) = unsafe {
        (
            _mm_loadu_si128(p.cast::<__m128i>()),
            _mm_loadu_si128(p.add(step).cast::<__m128i>()),
            _mm_loadu_si128(p.add(2 * step).cast::<__m128i>()),
        )
    };
    let starts = if WIDE {
        // Each 16-bit lane all ones or all zeros, packed to one byte per sample.
        let wide = _mm_and_si128(_mm_cmpeq_epi16(a, b), _mm_cmpeq_epi16(b, c));
        _mm_packs_epi16(wide, _mm_setzero_si128())
    } else {
        _mm_and_si128(_mm_cmpeq_epi8(a, b), _mm_cmpeq_epi8(b, c))
    };
    _mm_movemask_epi8(starts) as u32
}

impl Sample for u8 {
    const WIDE: bool = false;
    const CHUNK: usize = 16;

    #[inline(always)]
    fn run_starts(s: &[u8], i: usize) -> u32 {
        let w = &s[i..i + Self::CHUNK + 2];
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: `w` holds 16 bytes and two more samples.
            unsafe { sse2_run_starts::<false>(w.as_ptr()) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            run_starts_scalar(w, 0, Self::CHUNK)
        }
    }
}

impl Sample for u16 {
    const WIDE: bool = true;
    const CHUNK: usize = 8;

    #[inline(always)]
    fn run_starts(s: &[u16], i: usize) -> u32 {
        let w = &s[i..i + Self::CHUNK + 2];
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: `w` holds 16 bytes and two more samples.
            unsafe { sse2_run_starts::<true>(w.as_ptr().cast()) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            run_starts_scalar(w, 0, Self::CHUNK)
        }
    }
}

/// What a segment's scan is told: its tokens, in order.
trait Sink {
    /// A sample's two bytes as literals.
    fn literal(&mut self, v: u16);
    /// Consecutive samples as literals (at most [`Sample::CHUNK`]; only the last may be the
    /// first sample of a run, which [`Sink::run`] then gives).
    #[inline(always)]
    fn literals<T: Sample>(&mut self, samples: &[T]) {
        for &v in samples {
            self.literal(v.into());
        }
    }
    /// The next `k` samples repeat the one before: a match of `2k` bytes at distance 2.
    fn run(&mut self, k: usize);
}

/// Walks a segment's tokens: a literal sample, then, when the next two or more samples repeat
/// it, a run. A vector compare finds where runs start in [`Sample::CHUNK`] samples at a time;
/// most chunks of a frame hold none and go to the sink as literals at once, and in the others
/// the literals up to each run's start go as one slice, so that the walk branches per run, not
/// per sample. The last samples, too few for a chunk, are walked one by one. Generic over the
/// sample type so that each loop is compiled for it.
#[inline(always)]
fn scan<T: Sample, S: Sink>(samples: &[T], sink: &mut S) {
    let n = samples.len();
    let mut i = 0;
    while i + T::CHUNK + 2 <= n {
        let start = i;
        let end = start + T::CHUNK;
        let mut starts = T::run_starts(samples, start);
        if starts == 0 {
            sink.literals(&samples[start..end]);
            i = end;
            continue;
        }
        // `starts`: the runs that start at `i` or later in this chunk.
        while starts != 0 {
            let p = start + starts.trailing_zeros() as usize;
            sink.literals(&samples[i..=p]);
            let k = run_length(samples, p);
            sink.run(k);
            i = p + 1 + k;
            if i >= end {
                break;
            }
            starts &= u32::MAX << (i - start);
        }
        if i < end {
            sink.literals(&samples[i..end]);
            i = end;
        }
    }
    while i < n {
        let v = samples[i];
        sink.literal(v.into());
        i += 1;
        if i + 1 < n && samples[i] == v && samples[i + 1] == v {
            let k = run_length(samples, i - 1);
            sink.run(k);
            i += k;
        }
    }
}

/// How many samples after `p` repeat it, up to [`MAX_RUN`]; at least the two a run starts
/// with (`s[p] == s[p + 1] == s[p + 2]`).
#[inline(always)]
fn run_length<T: Sample>(samples: &[T], p: usize) -> usize {
    let v = samples[p];
    let mut k = 2;
    while p + 1 + k < samples.len() && k < MAX_RUN && samples[p + 1 + k] == v {
        k += 1;
    }
    k
}

/// Samples per span of [`sampled_counts`], and those of each span counted (a quarter). The span
/// is prime so that the counted samples drift across the columns of a slice of any width,
/// instead of falling in the same columns row after row when the width is a multiple of it.
const SPAN: usize = 4099;
const COUNTED: usize = 1025;

/// The byte values of the first [`COUNTED`] samples of every [`SPAN`] of `samples` counted as
/// literals (16-bit samples: both bytes; 8-bit samples: the value, their zero high bytes are
/// added by the caller), and how many samples that was. In four tables so that equal
/// neighbouring samples (powder is nearly uniform) do not wait on each other's increments.
fn sampled_counts<T: Sample>(samples: &[T]) -> ([u32; LITLEN], usize) {
    let mut tables = [[0u32; 256]; 4];
    let count = |table: &mut [u32; 256], v: u16| {
        table[usize::from(v & 0xFF)] += 1;
        if T::WIDE {
            table[usize::from(v >> 8)] += 1;
        }
    };
    let [t0, t1, t2, t3] = &mut tables;
    let mut counted = 0;
    for span in samples.chunks(SPAN) {
        let part = &span[..span.len().min(COUNTED)];
        counted += part.len();
        let quads = part.chunks_exact(4);
        for &v in quads.remainder() {
            count(t0, v.into());
        }
        for q in quads {
            count(t0, q[0].into());
            count(t1, q[1].into());
            count(t2, q[2].into());
            count(t3, q[3].into());
        }
    }
    let mut freq = [0u32; LITLEN];
    for table in &tables {
        for (f, &g) in freq.iter_mut().zip(table) {
            *f += g;
        }
    }
    (freq, counted)
}

/// A code and its length in one word: the bits in the low half, the length in the high half.
fn packed(bits: u64, len: u32) -> u64 {
    bits | (u64::from(len) << 32)
}

/// Writes a segment's tokens with its codes.
struct Emit<const GRAY8: bool> {
    w: BitWriter,
    /// 8-bit samples: per value, its low byte's code followed by its high (zero) byte's;
    /// 16-bit samples: the code of each literal/length symbol. Both [`packed`].
    table: [u64; LITLEN],
    /// The length symbols' codes and the distance code, per run length.
    runs: Vec<u64>,
    /// 8-bit samples: the codes of the latest tokens, not yet written, `queued` of them. They
    /// go to [`BitWriter::put_all`] four at a time, whether they came from a chunk of
    /// literals or from the token-by-token walk around runs, so that the writer's pending bits
    /// stay in registers there too.
    queue: [u64; QUEUE],
    queued: usize,
}

/// [`Emit::queue`]'s room: up to [`QUEUE_FULL`] codes wait, then a token or a chunk of 16
/// literals may add to them before they are written.
const QUEUE: usize = 64;
const QUEUE_FULL: usize = 32;

impl<const GRAY8: bool> Emit<GRAY8> {
    fn new(w: BitWriter, codes: &[(u32, u32)]) -> Self {
        let code = |s: usize| (u64::from(codes[s].0), codes[s].1);
        let mut table = [0u64; LITLEN];
        for (s, t) in table.iter_mut().enumerate() {
            let (c, l) = code(s);
            *t = if GRAY8 && s < 256 {
                let (c0, l0) = code(0);
                packed(c | (c0 << l), l + l0)
            } else {
                packed(c, l)
            };
        }
        let dist = u64::from(reverse(DIST_CODE, 1));
        let runs = (0..=MAX_RUN)
            .map(|k| {
                if k < 2 {
                    return 0;
                }
                let (sym, extra_len, extra) = length_code(2 * k);
                let (c, l) = code(sym);
                let bits = c | (u64::from(extra) << l) | (dist << (l + extra_len));
                packed(bits, l + extra_len + 1)
            })
            .collect();
        Emit {
            w,
            table,
            runs,
            queue: [0; QUEUE],
            queued: 0,
        }
    }

    /// Queues an 8-bit sample's token; writes the queue's whole fours once it is full.
    #[inline(always)]
    fn queue(&mut self, code: u64) {
        self.queue[self.queued] = code;
        self.queued += 1;
        self.written_when_full();
    }

    #[inline(always)]
    fn written_when_full(&mut self) {
        if self.queued >= QUEUE_FULL {
            let whole = self.queued & !3;
            self.w.put_all(&self.queue[..whole]);
            self.queue.copy_within(whole..self.queued, 0);
            self.queued -= whole;
        }
    }

    /// The writer, with every queued code written.
    fn finish(mut self) -> BitWriter {
        self.w.put_all(&self.queue[..self.queued]);
        self.w
    }
}

impl<const GRAY8: bool> Sink for Emit<GRAY8> {
    #[inline(always)]
    fn literal(&mut self, v: u16) {
        if GRAY8 {
            self.queue(self.table[usize::from(v as u8)]);
        } else {
            let lo = self.table[usize::from(v & 0xFF)];
            let hi = self.table[usize::from(v >> 8)];
            let (l0, l1) = ((lo >> 32) as u32, (hi >> 32) as u32);
            self.w
                .put((lo & 0xFFFF_FFFF) | ((hi & 0xFFFF_FFFF) << l0), l0 + l1);
        }
    }

    #[inline(always)]
    fn literals<T: Sample>(&mut self, samples: &[T]) {
        if GRAY8 {
            // At most QUEUE_FULL - 1 codes wait: a chunk (16) fits behind them.
            let room = &mut self.queue[self.queued..self.queued + samples.len()];
            for (c, &v) in room.iter_mut().zip(samples) {
                *c = self.table[usize::from(v.into() as u8)];
            }
            self.queued += samples.len();
            self.written_when_full();
        } else {
            for &v in samples {
                self.literal(v.into());
            }
        }
    }

    #[inline(always)]
    fn run(&mut self, k: usize) {
        if GRAY8 {
            self.queue(self.runs[k]);
        } else {
            self.w.put_packed(self.runs[k]);
        }
    }
}

impl<'a> Segment<'a> {
    fn new(samples: Samples<'a>) -> Self {
        Segment { samples }
    }

    /// The symbol counts the segment's code is built from, in one pass without the run scan,
    /// over the first [`COUNTED`] samples of every [`SPAN`] (a quarter, spread evenly over the
    /// segment: the code of a million samples is as good from a quarter of them, and counting
    /// was a quarter of the coding's time): every counted sample as a literal (a sample inside a
    /// run too, which can only lengthen its run's code a little: runs are rare in camera frames,
    /// and a run of 129 samples costs a few bits whatever its code), every byte value, every
    /// length symbol and the end of block at least once, so that every token the scan then
    /// writes has a code whatever the samples not counted hold.
    fn frequencies(&self) -> [u32; LITLEN] {
        let mut freq = match self.samples {
            Samples::Gray8(s) => {
                let (mut freq, counted) = sampled_counts(s);
                // Every 8-bit sample's high byte is 0.
                freq[0] = freq[0].saturating_add(counted as u32);
                freq
            }
            Samples::Gray16(s) => sampled_counts(s).0,
        };
        for f in &mut freq {
            *f = (*f).max(1);
        }
        freq
    }

    /// One dynamic block; non-final segments end byte-aligned with an empty stored block.
    fn encode(&self, last: bool) -> Vec<u8> {
        let lengths = code_lengths(&self.frequencies(), 15);
        let codes = canonical_codes(&lengths);
        // About one byte a sample on camera frames; the vector grows where it is not enough.
        let mut w = BitWriter::with_capacity(self.samples.len() + 1024);
        w.put(u64::from(last), 1);
        w.put(2, 2);
        write_dynamic_header(&mut w, &lengths);
        let mut w = match self.samples {
            Samples::Gray8(s) => {
                let mut emit = Emit::<true>::new(w, &codes);
                scan(s, &mut emit);
                emit.finish()
            }
            Samples::Gray16(s) => {
                let mut emit = Emit::<false>::new(w, &codes);
                scan(s, &mut emit);
                emit.finish()
            }
        };
        let (c, l) = codes[EOB];
        w.put(u64::from(c), l);
        if !last {
            w.put(0, 3);
            w.align();
            w.bytes(&[0, 0, 0xFF, 0xFF]);
        }
        w.align();
        w.into_bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    fn inflate(parts: &[Vec<u8>]) -> Vec<u8> {
        let mut out = Vec::new();
        flate2::read::DeflateDecoder::new(&parts.concat()[..])
            .read_to_end(&mut out)
            .expect("one valid raw deflate stream");
        out
    }

    fn le(samples: Samples<'_>) -> Vec<u8> {
        let mut out = Vec::new();
        samples.extend_le(0..samples.len(), &mut out);
        out
    }

    #[test]
    fn gray8_and_gray16_samples_inflate_back() {
        // Noise, runs of every length around the limits, a flat tail, over several segments.
        let mut v8 = Vec::new();
        let mut x = 12345u32;
        for i in 0..(2 * SEGMENT + 777) {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            let run = (i / 1000) % 300;
            v8.push(if i % 1000 < run { 7 } else { (x >> 24) as u8 });
        }
        v8.extend(std::iter::repeat_n(0, 5000));
        let s = Samples::Gray8(&v8);
        assert_eq!(inflate(&deflate_samples(s)), le(s));
        let v16: Vec<u16> = v8
            .iter()
            .enumerate()
            .map(|(i, &v)| (u16::from(v) * 257).wrapping_add((i % 3) as u16))
            .collect();
        let s = Samples::Gray16(&v16);
        assert_eq!(inflate(&deflate_samples(s)), le(s));
        // Tiny inputs: one sample, one repeated, all alike.
        for v in [vec![5u8], vec![5, 5], vec![5, 5, 5], vec![9; 100_000]] {
            let s = Samples::Gray8(&v);
            assert_eq!(
                inflate(&deflate_samples(s)),
                le(s),
                "{:?}",
                &v[..3.min(v.len())]
            );
        }
    }

    #[test]
    fn values_only_where_the_counts_do_not_look_still_inflate_back() {
        // Every span's counted head holds 0-3 only; the values after it, 8-bit and both bytes of
        // 16-bit samples, are never counted and must still have codes.
        let v8: Vec<u8> = (0..3 * SPAN + 100)
            .map(|i| match i % SPAN {
                p if p < COUNTED => (p % 4) as u8,
                p => (p * 7 % 256) as u8,
            })
            .collect();
        let (counts, counted) = sampled_counts(&v8);
        assert_eq!(counted, 3 * COUNTED + 100);
        assert!(counts[4..256].iter().all(|&c| c == 0));
        let s = Samples::Gray8(&v8);
        assert_eq!(inflate(&deflate_samples(s)), le(s));
        let v16: Vec<u16> = v8.iter().map(|&v| u16::from(v) * 257).collect();
        let s = Samples::Gray16(&v16);
        assert_eq!(inflate(&deflate_samples(s)), le(s));
    }

    #[test]
    fn parts_in_groups_are_the_parts_at_once() {
        let v8: Vec<u8> = (0..(3 * SEGMENT + 5))
            .map(|i| (i % 251 / 3) as u8)
            .collect();
        let s = Samples::Gray8(&v8);
        let all = deflate_samples(s);
        assert_eq!(all.len(), 4);
        assert_eq!(inflate(&all), le(s));
        // Only the last part's block is final (BFINAL, the first bit of a part).
        let finals: Vec<u8> = all.iter().map(|part| part[0] & 1).collect();
        assert_eq!(finals, [0, 0, 0, 1]);
        for group in [1, 2, 3, 4, 9] {
            let mut sizes = Vec::new();
            let mut parts = Vec::new();
            deflate_samples_each(s, group, |g| {
                sizes.push(g.len());
                parts.extend(g);
                Ok::<(), ()>(())
            })
            .expect("no error");
            assert_eq!(parts, all, "groups of {group}");
            let expected: Vec<usize> = (0..4).step_by(group).map(|f| group.min(4 - f)).collect();
            assert_eq!(sizes, expected, "groups of {group}");
        }
        // The first error stops the coding.
        let mut calls = 0;
        let stopped = deflate_samples_each(s, 1, |_| {
            calls += 1;
            if calls == 2 {
                Err("full disk")
            } else {
                Ok(())
            }
        });
        assert_eq!((stopped, calls), (Err("full disk"), 2));
    }

    #[test]
    fn long_codes_four_in_a_row_inflate_back() {
        // A skewed histogram (value k about 2^-(k+1) of the time) and a few rare values in
        // groups of eight in a row: the rare ones get codes so long that four of them do not fit
        // one write, at every offset from the start of a chunk, between runs.
        let mut v8 = Vec::new();
        let mut x = 7u32;
        for i in 0..300_000usize {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            let common = ((x >> 8) | 1 << 12).trailing_zeros() as u8;
            let group = i % 16_001;
            v8.push(if group < 8 { 20 + group as u8 } else { common });
        }
        let s = Samples::Gray8(&v8);
        assert_eq!(inflate(&deflate_samples(s)), le(s));
        // Four rare samples' codes (each followed by the zero high byte's) exceed 56 bits.
        let lengths = code_lengths(&Segment::new(s).frequencies(), 15);
        let sample_bits = |v: usize| u32::from(lengths[v]) + u32::from(lengths[0]);
        assert!((20..28).all(|v| 4 * sample_bits(v) > 56), "{lengths:?}");
    }

    /// The tokens of a scan, as a sink records them.
    #[derive(Default)]
    struct Tokens(Vec<(bool, usize)>);

    impl Sink for Tokens {
        fn literal(&mut self, v: u16) {
            self.0.push((true, usize::from(v)));
        }
        fn run(&mut self, k: usize) {
            self.0.push((false, k));
        }
    }

    /// The scan sample by sample, without the chunks.
    fn reference_scan<T: Sample>(samples: &[T]) -> Vec<(bool, usize)> {
        let mut t = Tokens::default();
        let (n, mut i) = (samples.len(), 0);
        while i < n {
            let v = samples[i];
            t.literal(v.into());
            i += 1;
            if i + 1 < n && samples[i] == v && samples[i + 1] == v {
                let mut k = 2;
                while i + k < n && k < MAX_RUN && samples[i + k] == v {
                    k += 1;
                }
                t.run(k);
                i += k;
            }
        }
        t.0
    }

    #[test]
    fn chunked_scan_gives_the_tokens_of_the_sample_by_sample_scan() {
        // Few grey levels, so that pairs and runs of every length land at every offset of a
        // chunk, and the end of the input cuts chunks and runs.
        let mut x = 99u32;
        let mut v8 = Vec::new();
        for i in 0..20_000 {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            let r = (x >> 16) as usize;
            if r.is_multiple_of(7) {
                let run = r % 140;
                v8.extend(std::iter::repeat_n((i % 5) as u8, run));
            } else {
                v8.push((r % 3) as u8);
            }
        }
        let v16: Vec<u16> = v8.iter().map(|&v| u16::from(v) * 300).collect();
        for n in [0, 1, 2, 3, 17, 18, 19, 33, 1000, v8.len()] {
            let mut t = Tokens::default();
            scan(&v8[..n], &mut t);
            assert_eq!(t.0, reference_scan(&v8[..n]), "8-bit, {n} samples");
            let mut t = Tokens::default();
            scan(&v16[..n], &mut t);
            assert_eq!(t.0, reference_scan(&v16[..n]), "16-bit, {n} samples");
        }
        for i in 0..v8.len() - 18 {
            assert_eq!(
                u8::run_starts(&v8, i),
                run_starts_scalar(&v8, i, 16),
                "at {i}"
            );
        }
        for i in 0..v16.len() - 10 {
            assert_eq!(
                u16::run_starts(&v16, i),
                run_starts_scalar(&v16, i, 8),
                "at {i}"
            );
        }
    }
}
