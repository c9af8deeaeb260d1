//! The one matrix product the networks need, on a selectable single-threaded GEMM engine.
//!
//! Both engines take arbitrary row and column strides, so transposes cost nothing: the networks keep
//! activations as row-major `batch x width` matrices and weights as row-major `inputs x outputs`
//! matrices, and the backward pass reads them transposed through strides. See docs/benchmarks.md for the
//! measurement behind the default.

use serde::{Deserialize, Serialize};

/// Which GEMM implementation runs the matrix products.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Engine {
    /// The `gemm` crate (runtime SIMD dispatch, AVX-512 micro-kernels); the fastest measured here.
    #[default]
    Gemm,
    /// The `matrixmultiply` crate's `sgemm`: smaller and quicker to build, somewhat slower.
    MatrixMultiply,
}

/// A borrowed strided matrix: element `(i, j)` is `data[i * rs + j * cs]`.
#[derive(Debug, Clone, Copy)]
pub struct MatRef<'a> {
    /// Backing storage.
    pub data: &'a [f32],
    /// Row stride in elements.
    pub rs: usize,
    /// Column stride in elements.
    pub cs: usize,
}

impl<'a> MatRef<'a> {
    /// A row-major matrix with `cols` columns.
    pub fn rows(data: &'a [f32], cols: usize) -> Self {
        MatRef {
            data,
            rs: cols,
            cs: 1,
        }
    }

    /// The transpose of a row-major matrix with `cols` columns (so `cols` becomes the row count).
    pub fn transposed(data: &'a [f32], cols: usize) -> Self {
        MatRef {
            data,
            rs: 1,
            cs: cols,
        }
    }

    fn fits(&self, rows: usize, cols: usize) -> bool {
        rows == 0 || cols == 0 || (rows - 1) * self.rs + (cols - 1) * self.cs < self.data.len()
    }
}

/// `c[m x n] = a[m x k] * b[k x n] (+ c if accumulate)`, with `c` row-major of row stride `c_rs`.
///
/// # Panics
/// If a matrix's extent does not fit its slice: that is a shape bug in the caller, never user data, and
/// the check is what keeps the unsafe GEMM calls sound.
#[allow(clippy::too_many_arguments)]
pub fn matmul(
    engine: Engine,
    m: usize,
    n: usize,
    k: usize,
    a: MatRef<'_>,
    b: MatRef<'_>,
    c: &mut [f32],
    c_rs: usize,
    accumulate: bool,
) {
    assert!(a.fits(m, k), "matmul: lhs does not fit its slice");
    assert!(b.fits(k, n), "matmul: rhs does not fit its slice");
    assert!(
        m == 0 || n == 0 || (m - 1) * c_rs + n <= c.len(),
        "matmul: destination does not fit its slice"
    );
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !accumulate {
            for i in 0..m {
                c[i * c_rs..i * c_rs + n].fill(0.0);
            }
        }
        return;
    }
    match engine {
        Engine::Gemm => {
            // SAFETY: every index the product touches was bounds-checked above; the slices do not
            // alias (`c` is a unique borrow); strides fit isize because they index existing slices.
            unsafe {
                gemm::gemm(
                    m,
                    n,
                    k,
                    c.as_mut_ptr(),
                    1,
                    c_rs as isize,
                    accumulate,
                    a.data.as_ptr(),
                    a.cs as isize,
                    a.rs as isize,
                    b.data.as_ptr(),
                    b.cs as isize,
                    b.rs as isize,
                    if accumulate { 1.0 } else { 0.0 },
                    1.0,
                    false,
                    false,
                    false,
                    gemm::Parallelism::None,
                );
            }
        }
        Engine::MatrixMultiply => {
            // SAFETY: as above; matrixmultiply reads `c` only when beta != 0.
            unsafe {
                matrixmultiply::sgemm(
                    m,
                    k,
                    n,
                    1.0,
                    a.data.as_ptr(),
                    a.rs as isize,
                    a.cs as isize,
                    b.data.as_ptr(),
                    b.rs as isize,
                    b.cs as isize,
                    if accumulate { 1.0 } else { 0.0 },
                    c.as_mut_ptr(),
                    c_rs as isize,
                    1,
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn engines_agree_with_naive_product_and_transposes() {
        let (m, n, k) = (5, 7, 3);
        let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..n * k).map(|i| (i as f32 * 0.11).cos()).collect();
        for engine in [Engine::Gemm, Engine::MatrixMultiply] {
            // c = a * b^T where b is stored row-major n x k.
            let mut c = vec![1.0f32; m * n];
            matmul(
                engine,
                m,
                n,
                k,
                MatRef::rows(&a, k),
                MatRef::transposed(&b, k),
                &mut c,
                n,
                true,
            );
            for i in 0..m {
                for j in 0..n {
                    let want: f32 = 1.0 + (0..k).map(|t| a[i * k + t] * b[j * k + t]).sum::<f32>();
                    assert!((c[i * n + j] - want).abs() < 1e-5, "{engine:?}");
                }
            }
        }
    }
}
