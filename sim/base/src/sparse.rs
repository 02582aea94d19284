//! Compressed sparse row (CSR) matrices for the system matrix H and its Gram matrix HᵀH.
//!
//! Storage follows scipy's CSR (`indptr`, `indices`, `data`), with f32 values (H is a Monte
//! Carlo estimate; f32 holds it to 6·10⁻⁸ relative) and f64 arithmetic in every product.
//! Every product runs in a fixed order per output element, so results are bit-identical for
//! any thread count (parallel loops split the *outputs*, never a floating-point sum).

use rayon::prelude::*;

/// A sparse matrix in CSR form.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CsrMatrix {
    /// Number of rows.
    pub rows: usize,
    /// Number of columns.
    pub cols: usize,
    /// Row pointers (length rows + 1, starting at 0, ending at nnz).
    pub indptr: Vec<u64>,
    /// Column of every stored entry (sorted within a row).
    pub indices: Vec<u32>,
    /// Value of every stored entry.
    pub data: Vec<f32>,
}

/// Rows per parallel task in products (large enough to amortise scheduling).
const ROW_CHUNK: usize = 256;

impl CsrMatrix {
    /// An empty rows × cols matrix.
    pub fn zeros(rows: usize, cols: usize) -> Self {
        CsrMatrix {
            rows,
            cols,
            indptr: vec![0; rows + 1],
            indices: Vec::new(),
            data: Vec::new(),
        }
    }

    /// Number of stored entries.
    pub fn nnz(&self) -> usize {
        self.data.len()
    }

    /// Range of entries of row `r`.
    #[inline]
    pub fn row_range(&self, r: usize) -> std::ops::Range<usize> {
        self.indptr[r] as usize..self.indptr[r + 1] as usize
    }

    /// y = A·x (f64 accumulation, parallel over rows).
    pub fn mul_vec(&self, x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; self.rows];
        self.mul_vec_into(x, &mut y);
        y
    }

    /// y = A·x into `y` (f64 accumulation, parallel over rows).
    pub fn mul_vec_into(&self, x: &[f64], y: &mut [f64]) {
        assert_eq!(x.len(), self.cols, "mul_vec: x has the wrong length");
        assert_eq!(y.len(), self.rows, "mul_vec: y has the wrong length");
        y.par_chunks_mut(ROW_CHUNK)
            .enumerate()
            .for_each(|(chunk, ys)| {
                let r0 = chunk * ROW_CHUNK;
                for (k, yr) in ys.iter_mut().enumerate() {
                    let range = self.row_range(r0 + k);
                    let mut acc = 0.0;
                    for (&c, &v) in self.indices[range.clone()].iter().zip(&self.data[range]) {
                        acc += f64::from(v) * x[c as usize];
                    }
                    *yr = acc;
                }
            });
    }

    /// The transpose, also in CSR form (i.e. A in CSC form). Entries of each output row are
    /// in increasing column order.
    pub fn transpose(&self) -> CsrMatrix {
        let mut counts = vec![0u64; self.cols + 1];
        for &c in &self.indices {
            counts[c as usize + 1] += 1;
        }
        for i in 0..self.cols {
            counts[i + 1] += counts[i];
        }
        let indptr = counts.clone();
        let mut next = counts;
        let mut indices = vec![0u32; self.nnz()];
        let mut data = vec![0f32; self.nnz()];
        for r in 0..self.rows {
            for e in self.row_range(r) {
                let c = self.indices[e] as usize;
                let dst = next[c] as usize;
                next[c] += 1;
                indices[dst] = r as u32;
                data[dst] = self.data[e];
            }
        }
        CsrMatrix {
            rows: self.cols,
            cols: self.rows,
            indptr,
            indices,
            data,
        }
    }

    /// Checks the CSR invariants; returns a one-line description of the first violation.
    pub fn check(&self) -> Result<(), String> {
        if self.indptr.len() != self.rows + 1 {
            return Err(format!(
                "indptr has {} entries, expected rows + 1 = {}",
                self.indptr.len(),
                self.rows + 1
            ));
        }
        if self.indptr[0] != 0 || self.indptr[self.rows] as usize != self.nnz() {
            return Err("indptr must start at 0 and end at nnz".into());
        }
        if self.indices.len() != self.data.len() {
            return Err("indices and data differ in length".into());
        }
        if self.cols > u32::MAX as usize {
            return Err(format!("{} columns exceed the u32 index range", self.cols));
        }
        for r in 0..self.rows {
            if self.indptr[r] > self.indptr[r + 1] {
                return Err(format!("indptr decreases at row {r}"));
            }
        }
        if let Some(&c) = self.indices.iter().find(|&&c| c as usize >= self.cols) {
            return Err(format!(
                "column index {c} is out of range (cols = {})",
                self.cols
            ));
        }
        Ok(())
    }

    /// Densifies row `r` into `out` (length cols), as f64.
    pub fn row_dense_into(&self, r: usize, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        for e in self.row_range(r) {
            out[self.indices[e] as usize] += f64::from(self.data[e]);
        }
    }

    /// The block row [A₀ A₁ … A_{N−1}] of matrices with equal row counts: row r holds A₀'s
    /// entries of row r, then A₁'s with columns shifted by A₀'s column count, and so on
    /// (sorted columns stay sorted). `None` if the row counts differ or a column index would
    /// not fit in 32 bits.
    pub fn hstack(blocks: &[&CsrMatrix]) -> Option<CsrMatrix> {
        let rows = blocks.first().map_or(0, |b| b.rows);
        if blocks.iter().any(|b| b.rows != rows) {
            return None;
        }
        let cols = blocks
            .iter()
            .try_fold(0usize, |a, b| a.checked_add(b.cols))
            .filter(|&c| c <= u32::MAX as usize)?;
        let nnz: usize = blocks.iter().map(|b| b.nnz()).sum();
        let mut m = CsrMatrix {
            rows,
            cols,
            indptr: Vec::with_capacity(rows + 1),
            indices: Vec::with_capacity(nnz),
            data: Vec::with_capacity(nnz),
        };
        m.indptr.push(0);
        for r in 0..rows {
            let mut shift = 0u32;
            for b in blocks {
                let range = b.row_range(r);
                m.indices
                    .extend(b.indices[range.clone()].iter().map(|&c| c + shift));
                m.data.extend_from_slice(&b.data[range]);
                shift += b.cols as u32;
            }
            m.indptr.push(m.indices.len() as u64);
        }
        Some(m)
    }

    /// Splits the columns into `n` equal blocks (the inverse of [`CsrMatrix::hstack`]);
    /// `None` unless the column count is a multiple of `n` (n ≥ 1).
    pub fn hsplit(&self, n: usize) -> Option<Vec<CsrMatrix>> {
        if n == 0 || self.cols % n != 0 {
            return None;
        }
        let k = self.cols / n;
        let mut out: Vec<CsrMatrix> = (0..n)
            .map(|_| CsrMatrix {
                rows: self.rows,
                cols: k,
                indptr: Vec::with_capacity(self.rows + 1),
                indices: Vec::new(),
                data: Vec::new(),
            })
            .collect();
        for b in &mut out {
            b.indptr.push(0);
        }
        for r in 0..self.rows {
            for e in self.row_range(r) {
                let c = self.indices[e] as usize;
                let b = &mut out[c / k];
                b.indices.push((c % k) as u32);
                b.data.push(self.data[e]);
            }
            for b in &mut out {
                b.indptr.push(b.indices.len() as u64);
            }
        }
        Some(out)
    }

    /// Sum of squares of all entries (f64, in order).
    pub fn frobenius_sq(&self) -> f64 {
        self.data.iter().map(|&v| f64::from(v) * f64::from(v)).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> CsrMatrix {
        // [[1, 0, 2],
        //  [0, 0, 0],
        //  [0, 3, 4]]
        CsrMatrix {
            rows: 3,
            cols: 3,
            indptr: vec![0, 2, 2, 4],
            indices: vec![0, 2, 1, 2],
            data: vec![1.0, 2.0, 3.0, 4.0],
        }
    }

    #[test]
    fn products_and_transpose() {
        let a = small();
        a.check().unwrap();
        assert_eq!(a.mul_vec(&[1.0, 10.0, 100.0]), vec![201.0, 0.0, 430.0]);
        let t = a.transpose();
        t.check().unwrap();
        assert_eq!(t.indptr, vec![0, 1, 2, 4]);
        assert_eq!(t.indices, vec![0, 2, 0, 2]);
        assert_eq!(t.data, vec![1.0, 3.0, 2.0, 4.0]);
        assert_eq!(t.transpose(), a);
        let mut row = vec![0.0; 3];
        a.row_dense_into(2, &mut row);
        assert_eq!(row, vec![0.0, 3.0, 4.0]);
        assert_eq!(a.frobenius_sq(), 30.0);
    }

    #[test]
    fn hstack_and_hsplit_are_inverse() {
        let a = small();
        let mut b = small();
        b.data = vec![5.0, 6.0, 7.0, 8.0];
        let s = CsrMatrix::hstack(&[&a, &b]).unwrap();
        s.check().unwrap();
        assert_eq!((s.rows, s.cols), (3, 6));
        // [A B] x = A x₁ + B x₂.
        let x = [1.0, 10.0, 100.0, 2.0, 20.0, 200.0];
        let (ya, yb) = (a.mul_vec(&x[..3]), b.mul_vec(&x[3..]));
        let y = s.mul_vec(&x);
        for i in 0..3 {
            assert_eq!(y[i], ya[i] + yb[i]);
        }
        assert_eq!(s.hsplit(2).unwrap(), vec![a.clone(), b]);
        assert!(s.hsplit(4).is_none());
        let short = CsrMatrix::zeros(2, 3);
        assert!(CsrMatrix::hstack(&[&a, &short]).is_none());
    }

    #[test]
    fn check_finds_errors() {
        let mut a = small();
        a.indices[1] = 3;
        assert!(a.check().unwrap_err().contains("out of range"));
        let mut b = small();
        b.indptr[2] = 1;
        assert!(b.check().unwrap_err().contains("decreases"));
    }
}
