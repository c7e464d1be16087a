//! Huffman codes of a deflate block (RFC 1951 3.2): code lengths limited to 15 bits, canonical
//! codes, the dynamic block header, and the bit writer the block is written with.

/// LSB-first bit packing without a branch per code: the pending bits are stored 8 bytes at a
/// time into a small buffer and the write position moves by the whole bytes among them; the
/// buffer goes to the output vector when nearly full.
pub(super) struct BitWriter {
    out: Vec<u8>,
    buf: [u8; BIT_BUF],
    bits: Pending,
}

/// A [`BitWriter`]'s position and pending bits: copied into a local for a loop of codes, so that
/// they stay in registers (as fields beside the buffer they went through memory at every code).
#[derive(Clone, Copy)]
struct Pending {
    /// Whole bytes in the buffer.
    pos: usize,
    /// Pending bits, `n` of them (fewer than 8 between codes).
    acc: u64,
    n: u32,
}

impl Pending {
    /// Appends the `len` (≤ 56) low bits of `bits`, first bit first (no bit above `len` set),
    /// and stores the whole bytes; `pos + 8` must be within `buf`.
    #[inline(always)]
    fn put(&mut self, buf: &mut [u8; BIT_BUF], bits: u64, len: u32) {
        self.acc |= bits << self.n;
        self.n += len;
        // At most 63 bits are pending: 7 whole bytes leave at most 7.
        buf[self.pos..self.pos + 8].copy_from_slice(&self.acc.to_le_bytes());
        let whole = self.n >> 3;
        self.pos += whole as usize;
        self.acc >>= whole * 8;
        self.n &= 7;
    }
}

/// Bytes a [`BitWriter`] gathers before they go to its output.
const BIT_BUF: usize = 1 << 12;

/// The low half of a [`super::packed`] code.
const CODE: u64 = 0xFFFF_FFFF;

impl BitWriter {
    pub(super) fn with_capacity(bytes: usize) -> Self {
        BitWriter {
            out: Vec::with_capacity(bytes),
            buf: [0; BIT_BUF],
            bits: Pending {
                pos: 0,
                acc: 0,
                n: 0,
            },
        }
    }

    /// Appends the `len` (≤ 56) low bits of `bits`, first bit first; no bit of `bits` above
    /// `len` is set.
    #[inline(always)]
    pub(super) fn put(&mut self, bits: u64, len: u32) {
        let mut p = self.bits;
        p.put(&mut self.buf, bits, len);
        self.bits = p;
        if self.bits.pos > BIT_BUF - 8 {
            self.spill();
        }
    }

    /// [`BitWriter::put`] of each [`super::packed`] code (≤ 32 bits) in turn, four codes at a
    /// time where together they have at most 56 bits (nearly always on camera frames: one store
    /// for four). The four are joined pairwise first, off the chain of pending bits that every
    /// store waits on; where they are too long, they go one at a time.
    #[inline(always)]
    pub(super) fn put_all(&mut self, codes: &[u64]) {
        let mut p = self.bits;
        let mut quads = codes.chunks_exact(4);
        for q in &mut quads {
            if p.pos > BIT_BUF - 32 {
                self.out.extend_from_slice(&self.buf[..p.pos]);
                p.pos = 0;
            }
            let (ab, lab) = join(q[0], q[1]);
            let (cd, lcd) = join(q[2], q[3]);
            if lab + lcd <= 56 {
                p.put(&mut self.buf, ab | (cd << lab), lab + lcd);
            } else {
                for &code in q {
                    p.put(&mut self.buf, code & CODE, (code >> 32) as u32);
                }
            }
        }
        self.bits = p;
        if self.bits.pos > BIT_BUF - 8 {
            self.spill();
        }
        for &code in quads.remainder() {
            self.put_packed(code);
        }
    }

    /// [`BitWriter::put`] of a [`super::packed`] code.
    #[inline(always)]
    pub(super) fn put_packed(&mut self, code: u64) {
        self.put(code & CODE, (code >> 32) as u32);
    }

    /// The buffer's whole bytes to the output.
    fn spill(&mut self) {
        self.out.extend_from_slice(&self.buf[..self.bits.pos]);
        self.bits.pos = 0;
    }

    /// Pads with zero bits to a byte boundary.
    pub(super) fn align(&mut self) {
        let p = &mut self.bits;
        if p.n > 0 {
            self.buf[p.pos] = p.acc as u8;
            p.pos += 1;
        }
        p.acc = 0;
        p.n = 0;
        self.spill();
    }

    /// Byte-aligned bytes (after [`BitWriter::align`]).
    pub(super) fn bytes(&mut self, b: &[u8]) {
        self.spill();
        self.out.extend_from_slice(b);
    }

    pub(super) fn into_bytes(mut self) -> Vec<u8> {
        self.spill();
        self.out
    }
}

/// Two [`super::packed`] codes (≤ 32 bits each, so that both fit one word) as one: the first's
/// bits, then the second's, and their length.
#[inline(always)]
fn join(a: u64, b: u64) -> (u64, u32) {
    let (la, lb) = ((a >> 32) as u32, (b >> 32) as u32);
    ((a & CODE) | ((b & CODE) << la), la + lb)
}

/// `code` (`len` bits) reversed: deflate sends Huffman codes most significant bit first into an
/// LSB-first stream.
pub(super) fn reverse(code: u32, len: u32) -> u32 {
    code.reverse_bits() >> (32 - len.max(1))
}

/// Canonical codes (RFC 1951 3.2.2) of `lengths`, reversed for LSB-first packing, as (code,
/// length).
pub(super) fn canonical_codes(lengths: &[u8]) -> Vec<(u32, u32)> {
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
pub(super) fn code_lengths(freq: &[u32], max_bits: u32) -> Vec<u8> {
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
pub(super) fn write_dynamic_header(w: &mut BitWriter, litlen: &[u8]) {
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
