//! The zigzag order of the coefficients in the data.

/// Natural (row-major) index of the k-th coefficient in zigzag order; the entries past 63 catch
/// a run that overshoots the block in corrupt data (they all write the last coefficient, as
/// stb_image does). 128 entries, so that `ZIGZAG[k & 127]` needs no bounds check.
pub(super) const ZIGZAG: [u8; 128] = zigzag();

const fn zigzag() -> [u8; 128] {
    let mut t = [63u8; 128];
    let mut k = 0;
    while k < 64 {
        t[k] = ORDER[k];
        k += 1;
    }
    t
}

const ORDER: [u8; 64] = [
    0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5, 12, 19, 26, 33, 40, 48, 41, 34, 27, 20,
    13, 6, 7, 14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51, 58, 59,
    52, 45, 38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63,
];
