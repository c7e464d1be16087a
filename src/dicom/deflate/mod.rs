//! Deflate (RFC 1951) of a slice's pixel data, fast: the samples, 16-bit little endian, coded as
//! literals with one dynamic Huffman code per segment, plus runs of a repeated sample as matches
//! at distance 2 (a sample is two bytes). No other string matching: on rectified camera frames
//! matches beyond runs are rare, and the literal codes are what makes the file small (on a
//! rectified D810 frame 12% larger than zlib's level 1 and 8% smaller than the miniz level 1
//! used before, at over three times zlib's speed; benches/peers/deflate_vs_zlib.py,
//! docs/benchmarks.md). 8-bit samples (the luma of JPEG frames, stored in 16 bits) are coded
//! as one table entry per sample: the low byte's code followed by the high (zero) byte's.
//!
//! Segments of [`SEGMENT`] samples are coded in parallel, each ending on a byte boundary with an
//! empty stored block (as zlib's sync flush and pigz do), so their concatenation is one stream;
//! the last one ends the stream.

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

/// The samples deflated, as parts of one raw deflate stream that `prefix` (an already
/// compressed, byte-aligned, non-final part, or nothing) opens; the last part ends the stream.
pub(crate) fn deflate_samples(samples: Samples<'_>) -> Vec<Vec<u8>> {
    let n = samples.len();
    let segments = n.div_ceil(SEGMENT).max(1);
    (0..segments)
        .into_par_iter()
        .map(|k| {
            let range = k * SEGMENT..((k + 1) * SEGMENT).min(n);
            let last = k + 1 == segments;
            Segment::new(samples.slice(range)).encode(last)
        })
        .collect()
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

/// What a segment's scan is told: its tokens, in order.
trait Sink {
    /// A sample's two bytes as literals.
    fn literal(&mut self, v: u16);
    /// The next `k` samples repeat the one before: a match of `2k` bytes at distance 2.
    fn run(&mut self, k: usize);
}

/// Walks a segment's tokens: a literal sample, then, when the next two or more samples repeat
/// it, a run. Generic over the sample type so that each loop is compiled for it.
#[inline(always)]
fn scan<T: Copy + PartialEq + Into<u16>, S: Sink>(samples: &[T], sink: &mut S) {
    let n = samples.len();
    let mut i = 0;
    while i < n {
        let v = samples[i];
        sink.literal(v.into());
        i += 1;
        // Most samples differ from the one before: one compare rejects a run.
        if i + 1 < n && samples[i] == v && samples[i + 1] == v {
            let mut k = 2;
            while i + k < n && k < MAX_RUN && samples[i + k] == v {
                k += 1;
            }
            sink.run(k);
            i += k;
        }
    }
}

/// Counts the symbols of a segment's block.
struct Histogram<const GRAY8: bool> {
    freq: [u32; LITLEN],
    /// 8-bit samples seen as literals: each also codes its zero high byte.
    literals: u32,
}

impl<const GRAY8: bool> Histogram<GRAY8> {
    /// The symbol counts of `samples` and how many 8-bit literals they hold.
    fn of<T: Copy + PartialEq + Into<u16>>(samples: &[T]) -> ([u32; LITLEN], u32) {
        let mut h = Histogram::<GRAY8> {
            freq: [0; LITLEN],
            literals: 0,
        };
        scan(samples, &mut h);
        (h.freq, h.literals)
    }
}

impl<const GRAY8: bool> Sink for Histogram<GRAY8> {
    #[inline(always)]
    fn literal(&mut self, v: u16) {
        if GRAY8 {
            self.freq[usize::from(v & 0xFF)] += 1;
            self.literals += 1;
        } else {
            self.freq[usize::from(v & 0xFF)] += 1;
            self.freq[usize::from(v >> 8)] += 1;
        }
    }

    #[inline(always)]
    fn run(&mut self, k: usize) {
        self.freq[length_code(2 * k).0] += 1;
    }
}

/// Writes a segment's tokens with its codes.
struct Emit<'c> {
    w: BitWriter,
    /// Per sample value (8-bit samples), its low byte's code followed by its high byte's.
    pairs: Vec<(u64, u32)>,
    codes: &'c [(u32, u32)],
    dist_bits: u64,
}

impl Sink for Emit<'_> {
    #[inline(always)]
    fn literal(&mut self, v: u16) {
        let (bits, len) = match self.pairs.get(usize::from(v)) {
            Some(&pair) => pair,
            None => {
                let (c0, l0) = self.codes[usize::from(v & 0xFF)];
                let (c1, l1) = self.codes[usize::from(v >> 8)];
                (u64::from(c0) | (u64::from(c1) << l0), l0 + l1)
            }
        };
        self.w.put(bits, len);
    }

    #[inline(always)]
    fn run(&mut self, k: usize) {
        let (sym, extra_len, extra) = length_code(2 * k);
        let (c, l) = self.codes[sym];
        self.w
            .put(u64::from(c) | (u64::from(extra) << l), l + extra_len);
        self.w.put(self.dist_bits, 1);
    }
}

impl<'a> Segment<'a> {
    fn new(samples: Samples<'a>) -> Self {
        Segment { samples }
    }

    /// Symbol counts of the segment's block (its end-of-block included).
    fn frequencies(&self) -> [u32; LITLEN] {
        let (mut freq, literals) = match self.samples {
            Samples::Gray8(s) => Histogram::<true>::of(s),
            Samples::Gray16(s) => Histogram::<false>::of(s),
        };
        // Every 8-bit sample's high byte is 0.
        freq[0] += literals;
        freq[EOB] = 1;
        freq
    }

    /// One dynamic block; non-final segments end byte-aligned with an empty stored block.
    fn encode(&self, last: bool) -> Vec<u8> {
        let lengths = code_lengths(&self.frequencies(), 15);
        let codes = canonical_codes(&lengths);
        // At most 30 bits per sample, and the header.
        let mut w = BitWriter::with_capacity(4 * self.samples.len() + 1024);
        w.put(u64::from(last), 1);
        w.put(2, 2);
        write_dynamic_header(&mut w, &lengths);
        let pair = |v: usize| {
            let (c0, l0) = codes[v];
            let (c1, l1) = codes[0];
            (u64::from(c0) | (u64::from(c1) << l0), l0 + l1)
        };
        let mut emit = Emit {
            w,
            pairs: match self.samples {
                Samples::Gray8(_) => (0..256).map(pair).collect(),
                Samples::Gray16(_) => Vec::new(),
            },
            codes: &codes,
            dist_bits: u64::from(reverse(DIST_CODE, 1)),
        };
        match self.samples {
            Samples::Gray8(s) => scan(s, &mut emit),
            Samples::Gray16(s) => scan(s, &mut emit),
        }
        let mut w = emit.w;
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

/// LSB-first bit packing, 32 bits flushed at a time.
struct BitWriter {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl BitWriter {
    fn with_capacity(bytes: usize) -> Self {
        BitWriter {
            out: Vec::with_capacity(bytes),
            acc: 0,
            n: 0,
        }
    }

    /// Appends the `len` (≤ 32) low bits of `bits`, first bit first.
    #[inline(always)]
    fn put(&mut self, bits: u64, len: u32) {
        self.acc |= bits << self.n;
        self.n += len;
        if self.n >= 32 {
            self.out.extend_from_slice(&(self.acc as u32).to_le_bytes());
            self.acc >>= 32;
            self.n -= 32;
        }
    }

    /// Pads with zero bits to a byte boundary and flushes.
    fn align(&mut self) {
        while self.n > 0 {
            self.out.push(self.acc as u8);
            self.acc >>= 8;
            self.n = self.n.saturating_sub(8);
        }
        self.acc = 0;
    }

    /// Byte-aligned bytes (after [`BitWriter::align`]).
    fn bytes(&mut self, b: &[u8]) {
        self.out.extend_from_slice(b);
    }

    fn into_bytes(self) -> Vec<u8> {
        self.out
    }
}

/// `code` (`len` bits) reversed: deflate sends Huffman codes most significant bit first into an
/// LSB-first stream.
fn reverse(code: u32, len: u32) -> u32 {
    code.reverse_bits() >> (32 - len.max(1))
}

/// Canonical codes (RFC 1951 3.2.2) of `lengths`, reversed for LSB-first packing, as (code,
/// length).
fn canonical_codes(lengths: &[u8]) -> Vec<(u32, u32)> {
    let mut count = [0u32; 16];
    for &l in lengths {
        count[usize::from(l)] += 1;
    }
    count[0] = 0;
    let mut next = [0u32; 16];
    let mut code = 0;
    for bits in 1..16 {
        code = (code + count[bits - 1]) << 1;
        next[bits] = code;
    }
    lengths
        .iter()
        .map(|&l| {
            let l = u32::from(l);
            if l == 0 {
                return (0, 0);
            }
            let c = next[l as usize];
            next[l as usize] += 1;
            (reverse(c, l), l)
        })
        .collect()
}

/// Huffman code lengths for `freq`, none over `max_bits`: optimal lengths (Moffat-Katajainen,
/// in place on the sorted frequencies), then lengths over the limit folded in as miniz and
/// zlib do (the codes stay complete), shortest codes to the most frequent symbols. Symbols with
/// no count get no code; a lone symbol gets a 1-bit code.
fn code_lengths(freq: &[u32], max_bits: u32) -> Vec<u8> {
    let mut used: Vec<(u32, usize)> = freq
        .iter()
        .enumerate()
        .filter(|(_, &f)| f > 0)
        .map(|(s, &f)| (f, s))
        .collect();
    let mut lengths = vec![0u8; freq.len()];
    match used.len() {
        0 => return lengths,
        1 => {
            lengths[used[0].1] = 1;
            return lengths;
        }
        _ => {}
    }
    used.sort_unstable();
    let mut a: Vec<u64> = used.iter().map(|&(f, _)| u64::from(f)).collect();
    minimum_redundancy(&mut a);
    // Code lengths, longest first (a[i] is the length of the i-th least frequent symbol).
    let max = max_bits as usize;
    let mut per_length = [0u32; 64];
    for &l in &a {
        per_length[(l as usize).min(63)] += 1;
    }
    let over: u32 = per_length[max + 1..].iter().sum();
    if over > 0 {
        per_length[max] += over;
        for c in per_length[max + 1..].iter_mut() {
            *c = 0;
        }
        let mut total: u64 = (1..=max)
            .map(|i| u64::from(per_length[i]) << (max - i))
            .sum();
        while total > 1 << max {
            per_length[max] -= 1;
            for i in (1..max).rev() {
                if per_length[i] != 0 {
                    per_length[i] -= 1;
                    per_length[i + 1] += 2;
                    break;
                }
            }
            total -= 1;
        }
    }
    // The most frequent symbols (end of `used`) get the shortest lengths.
    let mut symbols = used.iter().rev();
    for (len, &count) in per_length.iter().enumerate().take(max + 1).skip(1) {
        for _ in 0..count {
            if let Some(&(_, s)) = symbols.next() {
                lengths[s] = len as u8;
            }
        }
    }
    lengths
}

/// Moffat & Katajainen's in-place minimum-redundancy code: `a` holds frequencies in increasing
/// order and becomes the code lengths.
fn minimum_redundancy(a: &mut [u64]) {
    let n = a.len();
    // Phase 1: internal node weights, with parent pointers overwriting the leaves.
    a[0] += a[1];
    let (mut root, mut leaf) = (0usize, 2usize);
    for next in 1..n - 1 {
        // First child.
        if leaf >= n || a[root] < a[leaf] {
            a[next] = a[root];
            a[root] = next as u64;
            root += 1;
        } else {
            a[next] = a[leaf];
            leaf += 1;
        }
        // Second child.
        if leaf >= n || (root < next && a[root] < a[leaf]) {
            a[next] += a[root];
            a[root] = next as u64;
            root += 1;
        } else {
            a[next] += a[leaf];
            leaf += 1;
        }
    }
    // Phase 2: depths of the internal nodes.
    a[n - 2] = 0;
    for next in (0..n.saturating_sub(2)).rev() {
        a[next] = a[a[next] as usize] + 1;
    }
    // Phase 3: depths of the leaves.
    let (mut avail, mut used, mut depth) = (1i64, 0i64, 0u64);
    let (mut root, mut next) = (n as i64 - 2, n as i64 - 1);
    while avail > 0 {
        while root >= 0 && a[root as usize] == depth {
            used += 1;
            root -= 1;
        }
        while avail > used {
            a[next as usize] = depth;
            next -= 1;
            avail -= 1;
        }
        avail = 2 * used;
        depth += 1;
        used = 0;
    }
}

/// The dynamic block header after BFINAL/BTYPE: HLIT, HDIST, HCLEN, the code-length code and
/// the run-length-coded literal/length and distance code lengths.
fn write_dynamic_header(w: &mut BitWriter, litlen: &[u8]) {
    const ORDER: [usize; 19] = [
        16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15,
    ];
    let hlit = litlen
        .iter()
        .rposition(|&l| l > 0)
        .map_or(257, |i| i + 1)
        .max(257);
    let mut all: Vec<u8> = litlen[..hlit].to_vec();
    all.extend_from_slice(&[1, 1]);
    // Run-length coding of the lengths: (symbol, extra bits, extra value).
    let mut rle: Vec<(usize, u32, u32)> = Vec::new();
    let mut i = 0;
    while i < all.len() {
        let l = all[i];
        let mut run = 1;
        while i + run < all.len() && all[i + run] == l {
            run += 1;
        }
        let mut left = run;
        if l == 0 {
            while left >= 11 {
                let r = left.min(138);
                rle.push((18, 7, (r - 11) as u32));
                left -= r;
            }
            if left >= 3 {
                rle.push((17, 3, (left - 3) as u32));
                left = 0;
            }
        } else {
            rle.push((usize::from(l), 0, 0));
            left -= 1;
            while left >= 3 {
                let r = left.min(6);
                rle.push((16, 2, (r - 3) as u32));
                left -= r;
            }
        }
        for _ in 0..left {
            rle.push((usize::from(l), 0, 0));
        }
        i += run;
    }
    let mut freq = [0u32; 19];
    for &(s, _, _) in &rle {
        freq[s] += 1;
    }
    let cl_lengths = code_lengths(&freq, 7);
    let cl_codes = canonical_codes(&cl_lengths);
    let hclen = ORDER
        .iter()
        .rposition(|&s| cl_lengths[s] > 0)
        .map_or(4, |i| i + 1)
        .max(4);
    w.put((hlit - 257) as u64, 5);
    w.put(1, 5); // HDIST: two distance codes
    w.put((hclen - 4) as u64, 4);
    for &s in &ORDER[..hclen] {
        w.put(u64::from(cl_lengths[s]), 3);
    }
    for (s, extra_len, extra) in rle {
        let (c, l) = cl_codes[s];
        w.put(u64::from(c), l);
        if extra_len > 0 {
            w.put(u64::from(extra), extra_len);
        }
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
    fn lengths_are_limited_and_complete() {
        // Fibonacci frequencies force lengths far beyond 15 without the limit.
        let mut freq = vec![0u32; 40];
        let (mut a, mut b) = (1u32, 1u32);
        for f in freq.iter_mut() {
            *f = a;
            (a, b) = (b, a.saturating_add(b));
        }
        let lengths = code_lengths(&freq, 15);
        assert!(lengths.iter().all(|&l| (1..=15).contains(&l)));
        let kraft: f64 = lengths.iter().map(|&l| 0.5f64.powi(i32::from(l))).sum();
        assert!((kraft - 1.0).abs() < 1e-12, "Kraft sum {kraft}");
        // Unlimited lengths are optimal: the expected length of a known case.
        let lengths = code_lengths(&[1, 1, 2, 4], 15);
        assert_eq!(lengths, vec![3, 3, 2, 1]);
    }
}
