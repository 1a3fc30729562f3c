//! Small dense linear algebra for the host's least-squares fits (calibration, the offline
//! differentiator): a handful of parameters, so plain rows of `f64` are enough.

/// The inverse of the square matrix `a` (rows), by Gauss–Jordan elimination with partial
/// pivoting; `None` when a pivot vanishes (singular to working precision).
pub fn invert(mut a: Vec<Vec<f64>>) -> Option<Vec<Vec<f64>>> {
    let n = a.len();
    let mut inv: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| f64::from(u8::from(i == j))).collect())
        .collect();
    for c in 0..n {
        let piv = (c..n).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if a[piv][c].abs() < 1e-300 {
            return None;
        }
        a.swap(c, piv);
        inv.swap(c, piv);
        let d = a[c][c];
        for k in 0..n {
            a[c][k] /= d;
            inv[c][k] /= d;
        }
        for r in 0..n {
            if r != c {
                let f = a[r][c];
                if f != 0.0 {
                    for k in 0..n {
                        a[r][k] -= f * a[c][k];
                        inv[r][k] -= f * inv[c][k];
                    }
                }
            }
        }
    }
    Some(inv)
}

/// Least-squares polynomial y ≈ c₀ + c₁x + … + c_d x^d through `points` (x, y) by the normal
/// equations: the coefficients c₀ … c_d, or `None` when they are not determined (fewer
/// distinct x than d + 1). Keep x of order one (centred and scaled) for conditioning.
pub fn polyfit(points: impl IntoIterator<Item = (f64, f64)>, degree: usize) -> Option<Vec<f64>> {
    let n = degree + 1;
    let mut ata = vec![vec![0.0f64; n]; n];
    let mut atb = vec![0.0f64; n];
    for (x, y) in points {
        let mut p = 1.0;
        let powers: Vec<f64> = (0..n)
            .map(|_| {
                let v = p;
                p *= x;
                v
            })
            .collect();
        for ((row, r), &pi) in ata.iter_mut().zip(atb.iter_mut()).zip(&powers) {
            for (a, &pj) in row.iter_mut().zip(&powers) {
                *a += pi * pj;
            }
            *r += pi * y;
        }
    }
    let inv = invert(ata)?;
    Some(
        inv.iter()
            .map(|row| row.iter().zip(&atb).map(|(a, b)| a * b).sum::<f64>())
            .collect(),
    )
}
