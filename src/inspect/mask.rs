//! Boolean masks on the inspection grid: square dilation and erosion, bounding boxes and
//! connected blobs.

/// A row-major boolean image.
#[derive(Clone, Debug, PartialEq)]
pub struct Mask {
    pub rows: usize,
    pub cols: usize,
    pub on: Vec<bool>,
}

/// Inclusive cell box: rows r0..=r1, columns c0..=c1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellBox {
    pub r0: usize,
    pub c0: usize,
    pub r1: usize,
    pub c1: usize,
}

impl CellBox {
    pub fn cell(r: usize, c: usize) -> CellBox {
        CellBox {
            r0: r,
            c0: c,
            r1: r,
            c1: c,
        }
    }
    pub fn grow(&mut self, r: usize, c: usize) {
        self.r0 = self.r0.min(r);
        self.r1 = self.r1.max(r);
        self.c0 = self.c0.min(c);
        self.c1 = self.c1.max(c);
    }
    /// Grown by `k` cells on every side, within `rows` x `cols`.
    pub fn expand(self, k: usize, rows: usize, cols: usize) -> CellBox {
        CellBox {
            r0: self.r0.saturating_sub(k),
            c0: self.c0.saturating_sub(k),
            r1: (self.r1 + k).min(rows.saturating_sub(1)),
            c1: (self.c1 + k).min(cols.saturating_sub(1)),
        }
    }
    /// A box in the coordinates of a window back in the whole grid's.
    pub fn within(self, window: CellBox) -> CellBox {
        CellBox {
            r0: self.r0 + window.r0,
            c0: self.c0 + window.c0,
            r1: self.r1 + window.r0,
            c1: self.c1 + window.c0,
        }
    }
    pub fn union(self, o: CellBox) -> CellBox {
        CellBox {
            r0: self.r0.min(o.r0),
            c0: self.c0.min(o.c0),
            r1: self.r1.max(o.r1),
            c1: self.c1.max(o.c1),
        }
    }
}

impl Mask {
    pub fn new(rows: usize, cols: usize) -> Mask {
        Mask {
            rows,
            cols,
            on: vec![false; rows * cols],
        }
    }
    pub fn count(&self) -> usize {
        self.on.iter().filter(|&&b| b).count()
    }
    pub fn get(&self, r: usize, c: usize) -> bool {
        self.on[r * self.cols + c]
    }
    /// Cells on in both.
    pub fn and(&self, o: &Mask) -> Mask {
        self.zip(o, |a, b| a && b)
    }
    /// Cells on here and off in `o`.
    pub fn minus(&self, o: &Mask) -> Mask {
        self.zip(o, |a, b| a && !b)
    }
    pub fn or(&self, o: &Mask) -> Mask {
        self.zip(o, |a, b| a || b)
    }
    fn zip(&self, o: &Mask, f: impl Fn(bool, bool) -> bool) -> Mask {
        Mask {
            rows: self.rows,
            cols: self.cols,
            on: self.on.iter().zip(&o.on).map(|(&a, &b)| f(a, b)).collect(),
        }
    }

    /// The cells of `window` as a mask of their own.
    pub fn crop(&self, window: CellBox) -> Mask {
        let cols = window.c1 + 1 - window.c0;
        let on = (window.r0..=window.r1)
            .flat_map(|r| {
                self.on[r * self.cols + window.c0..=r * self.cols + window.c1]
                    .iter()
                    .copied()
            })
            .collect();
        Mask {
            rows: window.r1 + 1 - window.r0,
            cols,
            on,
        }
    }

    /// Every cell within `k` cells (square neighbourhood) of an on cell.
    pub fn dilate(&self, k: usize) -> Mask {
        if k == 0 {
            return self.clone();
        }
        let (rows, cols) = (self.rows, self.cols);
        let mut horizontal = vec![false; rows * cols];
        for r in 0..rows {
            let line = &self.on[r * cols..(r + 1) * cols];
            // Distance to the last on cell from the left and from the right.
            let mut last: Option<usize> = None;
            for c in 0..cols {
                if line[c] {
                    last = Some(c);
                }
                if last.is_some_and(|l| c - l <= k) {
                    horizontal[r * cols + c] = true;
                }
            }
            let mut next: Option<usize> = None;
            for c in (0..cols).rev() {
                if line[c] {
                    next = Some(c);
                }
                if next.is_some_and(|n| n - c <= k) {
                    horizontal[r * cols + c] = true;
                }
            }
        }
        let mut out = vec![false; rows * cols];
        for c in 0..cols {
            let mut last: Option<usize> = None;
            for r in 0..rows {
                if horizontal[r * cols + c] {
                    last = Some(r);
                }
                if last.is_some_and(|l| r - l <= k) {
                    out[r * cols + c] = true;
                }
            }
            let mut next: Option<usize> = None;
            for r in (0..rows).rev() {
                if horizontal[r * cols + c] {
                    next = Some(r);
                }
                if next.is_some_and(|n| n - r <= k) {
                    out[r * cols + c] = true;
                }
            }
        }
        Mask {
            rows,
            cols,
            on: out,
        }
    }

    /// Cells whose whole `k`-neighbourhood is on (cells beyond the border count as off).
    pub fn erode(&self, k: usize) -> Mask {
        if k == 0 {
            return self.clone();
        }
        // Pad by k so the border counts as off.
        let (rows, cols) = (self.rows + 2 * k, self.cols + 2 * k);
        let mut inv = Mask {
            rows,
            cols,
            on: vec![true; rows * cols],
        };
        for r in 0..self.rows {
            for c in 0..self.cols {
                inv.on[(r + k) * cols + c + k] = !self.get(r, c);
            }
        }
        let grown = inv.dilate(k);
        let mut out = Mask::new(self.rows, self.cols);
        for r in 0..self.rows {
            for c in 0..self.cols {
                out.on[r * self.cols + c] = !grown.on[(r + k) * cols + c + k];
            }
        }
        out
    }

    pub fn bbox(&self) -> Option<CellBox> {
        let mut b: Option<CellBox> = None;
        for (i, _) in self.on.iter().enumerate().filter(|(_, &v)| v) {
            let (r, c) = (i / self.cols, i % self.cols);
            match &mut b {
                Some(b) => b.grow(r, c),
                None => b = Some(CellBox::cell(r, c)),
            }
        }
        b
    }

    /// Turns on every cell of `b`.
    pub fn set_box(&mut self, b: CellBox) {
        for r in b.r0..=b.r1.min(self.rows.saturating_sub(1)) {
            for c in b.c0..=b.c1.min(self.cols.saturating_sub(1)) {
                self.on[r * self.cols + c] = true;
            }
        }
    }

    /// The largest 8-connected blob as a mask of its own.
    pub fn largest_blob(&self) -> Option<Mask> {
        self.labelled()
            .into_iter()
            .max_by_key(|cells| cells.len())
            .map(|cells| {
                let mut m = Mask::new(self.rows, self.cols);
                for i in cells {
                    m.on[i] = true;
                }
                m
            })
    }

    /// 8-connected blobs, each as its cells' indices.
    pub fn labelled(&self) -> Vec<Vec<usize>> {
        let mut seen = vec![false; self.on.len()];
        let mut out = Vec::new();
        for start in 0..self.on.len() {
            if !self.on[start] || seen[start] {
                continue;
            }
            seen[start] = true;
            let mut cells = vec![start];
            let mut k = 0;
            while k < cells.len() {
                let i = cells[k];
                k += 1;
                let (r, c) = (i / self.cols, i % self.cols);
                for rr in r.saturating_sub(1)..(r + 2).min(self.rows) {
                    for cc in c.saturating_sub(1)..(c + 2).min(self.cols) {
                        let j = rr * self.cols + cc;
                        if self.on[j] && !seen[j] {
                            seen[j] = true;
                            cells.push(j);
                        }
                    }
                }
            }
            out.push(cells);
        }
        out
    }

    /// With its holes filled: every off cell that cannot reach the border through off cells
    /// (4-connected) turned on.
    pub fn filled(&self) -> Mask {
        let (rows, cols) = (self.rows, self.cols);
        let mut outside = vec![false; rows * cols];
        let mut stack: Vec<usize> = (0..rows * cols)
            .filter(|&i| {
                let (r, c) = (i / cols, i % cols);
                (r == 0 || c == 0 || r + 1 == rows || c + 1 == cols) && !self.on[i]
            })
            .collect();
        for &i in &stack {
            outside[i] = true;
        }
        while let Some(i) = stack.pop() {
            let (r, c) = (i / cols, i % cols);
            let mut visit = |j: usize| {
                if !self.on[j] && !outside[j] {
                    outside[j] = true;
                    stack.push(j);
                }
            };
            if r > 0 {
                visit(i - cols);
            }
            if r + 1 < rows {
                visit(i + cols);
            }
            if c > 0 {
                visit(i - 1);
            }
            if c + 1 < cols {
                visit(i + 1);
            }
        }
        Mask {
            rows,
            cols,
            on: outside.iter().map(|o| !o).collect(),
        }
    }

    /// 8-connected blobs: (cells, box), largest first.
    pub fn blobs(&self) -> Vec<(usize, CellBox)> {
        let mut seen = vec![false; self.on.len()];
        let mut out = Vec::new();
        let mut stack = Vec::new();
        for start in 0..self.on.len() {
            if !self.on[start] || seen[start] {
                continue;
            }
            seen[start] = true;
            stack.push(start);
            let mut n = 0;
            let mut b = CellBox::cell(start / self.cols, start % self.cols);
            while let Some(i) = stack.pop() {
                n += 1;
                let (r, c) = (i / self.cols, i % self.cols);
                b.grow(r, c);
                for dr in -1i64..=1 {
                    for dc in -1i64..=1 {
                        let (rr, cc) = (r as i64 + dr, c as i64 + dc);
                        if rr < 0 || cc < 0 || rr >= self.rows as i64 || cc >= self.cols as i64 {
                            continue;
                        }
                        let j = rr as usize * self.cols + cc as usize;
                        if self.on[j] && !seen[j] {
                            seen[j] = true;
                            stack.push(j);
                        }
                    }
                }
            }
            out.push((n, b));
        }
        out.sort_by_key(|b| std::cmp::Reverse(b.0));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dot(rows: usize, cols: usize, cells: &[(usize, usize)]) -> Mask {
        let mut m = Mask::new(rows, cols);
        for &(r, c) in cells {
            m.on[r * cols + c] = true;
        }
        m
    }

    #[test]
    fn dilate_erode_bbox_and_blobs() {
        let m = dot(9, 9, &[(4, 4)]);
        let d = m.dilate(2);
        assert_eq!(d.count(), 25);
        assert_eq!(
            d.bbox(),
            Some(CellBox {
                r0: 2,
                c0: 2,
                r1: 6,
                c1: 6
            })
        );
        assert_eq!(d.erode(2), m);
        assert_eq!(d.erode(3).count(), 0);
        // A block touching the border erodes from the border too.
        let full = Mask {
            rows: 4,
            cols: 4,
            on: vec![true; 16],
        };
        assert_eq!(full.erode(1).count(), 4);
        let two = dot(9, 9, &[(0, 0), (1, 1), (7, 7)]);
        let blobs = two.blobs();
        assert_eq!(blobs.len(), 2);
        assert_eq!(blobs[0].0, 2);
        assert_eq!(blobs[1].1, CellBox::cell(7, 7));
    }
}
