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

/// A linear least-squares fit y ≈ Σ cⱼ xⱼ: the coefficients, the inverse of the normal matrix
/// (cᵢ's variance is `inv_normal[i][i]` times the noise variance), the residual sum of
/// squares and the number of rows.
#[derive(Clone, Debug, PartialEq)]
pub struct LeastSquares {
    /// The coefficients cⱼ.
    pub coef: Vec<f64>,
    /// (AᵀA)⁻¹ of the design matrix A (its rows are the regressors).
    pub inv_normal: Vec<Vec<f64>>,
    /// Σ (y − Σ cⱼ xⱼ)².
    pub rss: f64,
    /// Number of rows.
    pub rows: usize,
}

impl LeastSquares {
    /// The standard error of coefficient `j` with the noise variance estimated from the
    /// residuals (rss over the degrees of freedom); `None` without a degree of freedom.
    pub fn std_error(&self, j: usize) -> Option<f64> {
        let dof = self.rows.checked_sub(self.coef.len()).filter(|&d| d > 0)?;
        let v = self.inv_normal.get(j)?.get(j)? * self.rss / dof as f64;
        (v >= 0.0).then(|| v.sqrt())
    }
}

/// Least squares of `rows` (regressors x₀ … x_{n−1}, y) by the normal equations, each column
/// scaled to unit RMS first (regressors of very different sizes stay well conditioned);
/// `None` with a regressor that is zero throughout or a singular normal matrix.
pub fn least_squares(rows: &[(Vec<f64>, f64)], n: usize) -> Option<LeastSquares> {
    let mut scale = vec![0.0f64; n];
    for (x, _) in rows {
        for (s, v) in scale.iter_mut().zip(x) {
            *s += v * v;
        }
    }
    for s in &mut scale {
        *s = s.sqrt();
        if !(s.is_finite() && *s > 0.0) {
            return None;
        }
    }
    let mut ata = vec![vec![0.0f64; n]; n];
    let mut atb = vec![0.0f64; n];
    for (x, y) in rows {
        for i in 0..n {
            let xi = x.get(i)? / scale[i];
            for j in 0..n {
                ata[i][j] += xi * x.get(j)? / scale[j];
            }
            atb[i] += xi * y;
        }
    }
    let inv = invert(ata)?;
    let coef: Vec<f64> = (0..n)
        .map(|i| inv[i].iter().zip(&atb).map(|(a, b)| a * b).sum::<f64>() / scale[i])
        .collect();
    let inv_normal = (0..n)
        .map(|i| (0..n).map(|j| inv[i][j] / (scale[i] * scale[j])).collect())
        .collect();
    let rss = rows
        .iter()
        .map(|(x, y)| {
            let r = y - x.iter().zip(&coef).map(|(a, c)| a * c).sum::<f64>();
            r * r
        })
        .sum();
    Some(LeastSquares {
        coef,
        inv_normal,
        rss,
        rows: rows.len(),
    })
}

/// Least-squares polynomial y ≈ c₀ + c₁x + … + c_d x^d through `points` (x, y) by the normal
/// equations: the coefficients c₀ … c_d, or `None` when they are not determined (fewer
/// distinct x than d + 1). Keep x of order one (centred and scaled) for conditioning.
pub fn polyfit(points: impl IntoIterator<Item = (f64, f64)>, degree: usize) -> Option<Vec<f64>> {
    let rows: Vec<(Vec<f64>, f64)> = points
        .into_iter()
        .map(|(x, y)| {
            let mut p = 1.0;
            let powers = (0..=degree)
                .map(|_| {
                    let v = p;
                    p *= x;
                    v
                })
                .collect();
            (powers, y)
        })
        .collect();
    least_squares(&rows, degree + 1).map(|f| f.coef)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fit through noisy points is the closed-form straight line, and its standard error
    /// the textbook one: σ(slope)² = s² / Σ(x − x̄)².
    #[test]
    fn least_squares_recovers_a_line_and_its_standard_error() {
        let xs: Vec<f64> = (0..20).map(|i| f64::from(i) * 0.5).collect();
        // A deterministic ±0.1 "noise" that sums to zero.
        let rows: Vec<(Vec<f64>, f64)> = xs
            .iter()
            .enumerate()
            .map(|(i, &x)| {
                (
                    vec![1.0, 1e3 * x],
                    2.0 - 3e-3 * x + if i % 2 == 0 { 0.1 } else { -0.1 },
                )
            })
            .collect();
        let f = least_squares(&rows, 2).expect("determined");
        // The closed-form straight line through the same points.
        let mean = xs.iter().sum::<f64>() / 20.0;
        let ybar = rows.iter().map(|r| r.1).sum::<f64>() / 20.0;
        let sxx: f64 = xs.iter().map(|x| (1e3 * (x - mean)).powi(2)).sum();
        let sxy: f64 = xs
            .iter()
            .zip(&rows)
            .map(|(x, r)| 1e3 * (x - mean) * (r.1 - ybar))
            .sum();
        let slope = sxy / sxx;
        assert!((f.coef[1] - slope).abs() < 1e-12, "{:?} vs {slope}", f.coef);
        assert!(
            (f.coef[0] - (ybar - slope * 1e3 * mean)).abs() < 1e-9,
            "{:?}",
            f.coef
        );
        let s2 = f.rss / 18.0;
        let want = (s2 / sxx).sqrt();
        let got = f.std_error(1).unwrap();
        assert!(
            (got - want).abs() < 1e-9 * want.max(1e-12) + 1e-15,
            "{got} vs {want}"
        );
        // A column of zeros is not determined.
        let zero: Vec<(Vec<f64>, f64)> = xs.iter().map(|&x| (vec![1.0, 0.0], x)).collect();
        assert!(least_squares(&zero, 2).is_none());
    }

    #[test]
    fn polyfit_recovers_a_cubic() {
        let c = polyfit(
            (0..9).map(|i| {
                let x = f64::from(i) / 4.0 - 1.0;
                (x, 0.5 - x + 2.0 * x * x * x)
            }),
            3,
        )
        .unwrap();
        for (got, want) in c.iter().zip([0.5, -1.0, 0.0, 2.0]) {
            assert!((got - want).abs() < 1e-12, "{c:?}");
        }
    }
}
