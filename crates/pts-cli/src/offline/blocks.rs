//! Phase 0: the trace averaged into blocks (the controller's samples), and the window
//! statistics the other phases share.

use grasp::estimate::{to_micro as micro, Sample};
use pts::Model;

use super::{Block, OfflineConfig, OfflineError, TraceSample, MIN_RATE_HZ, OUTLIER_RAD};

/// Averages the trace into blocks (into `scratch`); returns how many were written and the
/// block length used (s). Rows must be in non-decreasing time; equal times are fine.
pub fn make_blocks<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    rows: &[TraceSample],
    scratch: &mut [Block],
) -> Result<(usize, f64), OfflineError> {
    if !(cfg.block_s.is_finite() && cfg.block_s > 0.0) || scratch.is_empty() {
        return Err(OfflineError::BadConfig);
    }
    let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
        return Err(OfflineError::TooShort);
    };
    let mut prev = first.t_s;
    for (i, r) in rows.iter().enumerate() {
        if !(r.t_s.is_finite() && r.theta_a_rad.is_finite() && r.torque_nm.is_finite()) {
            return Err(OfflineError::NonFinite { row: i as u32 });
        }
        if r.t_s < prev {
            return Err(OfflineError::NonMonotoneTime { row: i as u32 });
        }
        prev = r.t_s;
    }
    for (i, w) in rows.windows(3).enumerate() {
        if let [a, b, c] = w {
            let (d1, d2) = (b.theta_a_rad - a.theta_a_rad, b.theta_a_rad - c.theta_a_rad);
            if d1.abs() > OUTLIER_RAD
                && d2.abs() > OUTLIER_RAD
                && d1.signum() == d2.signum()
                && (c.theta_a_rad - a.theta_a_rad).abs() < 0.25 * OUTLIER_RAD
            {
                return Err(OfflineError::Outlier { row: i as u32 + 1 });
            }
        }
    }
    let span = last.t_s - first.t_s;
    if rows.len() > 1 && span > 0.0 {
        let rate = (rows.len() - 1) as f64 / span;
        if rate < MIN_RATE_HZ * 0.98 {
            return Err(OfflineError::SampleRateTooLow {
                rate_hz: rate as u32,
            });
        }
    }
    let cap = scratch.len() as f64;
    let block = if span / cfg.block_s > cap - 1.0 {
        span / (cap - 1.0)
    } else {
        cfg.block_s
    };
    if !(block > 0.0) {
        return Err(OfflineError::TooShort);
    }
    let mut n = 0usize;
    let mut cur: Option<(u32, f64, f64, f64, u32, u32)> = None; // idx, Σt, Σθ, ΣT, count, first
    let mut flush = |c: (u32, f64, f64, f64, u32, u32), n: &mut usize| {
        let k = f64::from(c.4);
        let th = c.2 / k;
        let resid = model
            .free_from_theta_a(R::from_f64(th))
            .map(|f| c.3 / k - f.ta.to_f64())
            .unwrap_or(f64::NAN);
        if let Some(slot) = scratch.get_mut(*n) {
            *slot = Block {
                index: c.0,
                t_s: c.1 / k,
                theta_a_rad: th,
                torque_nm: c.3 / k,
                resid_nm: resid,
                first_row: c.5,
            };
            *n += 1;
        }
    };
    for (i, r) in rows.iter().enumerate() {
        let idx = ((r.t_s - first.t_s) / block) as u32;
        match cur {
            Some(ref mut c) if c.0 == idx => {
                c.1 += r.t_s;
                c.2 += r.theta_a_rad;
                c.3 += r.torque_nm;
                c.4 = c.4.saturating_add(1);
            }
            _ => {
                if let Some(c) = cur {
                    flush(c, &mut n);
                }
                cur = Some((idx, r.t_s, r.theta_a_rad, r.torque_nm, 1, i as u32));
            }
        }
    }
    if let Some(c) = cur {
        flush(c, &mut n);
    }
    Ok((n, block))
}

/// Median of up to 64 values (NaN ignored); `None` when empty.
pub(super) fn median(vals: impl Iterator<Item = f64>) -> Option<f64> {
    let mut buf = [0.0f64; 64];
    let mut n = 0;
    for v in vals {
        if v.is_nan() {
            continue;
        }
        if let Some(s) = buf.get_mut(n) {
            *s = v;
            n += 1;
        }
    }
    let s = buf.get_mut(..n)?;
    s.sort_unstable_by(|a, b| a.partial_cmp(b).unwrap_or(core::cmp::Ordering::Equal));
    if n == 0 {
        return None;
    }
    let a = s.get((n - 1) / 2).copied()?;
    let b = s.get(n / 2).copied()?;
    Some(0.5 * (a + b))
}

/// Least-squares line θ = a + b·t over a window; returns (slope, max |residual|).
pub(super) fn line_in_time(w: &[Block]) -> Option<(f64, f64)> {
    let n = w.len() as f64;
    if w.len() < 3 {
        return None;
    }
    let mt = w.iter().map(|b| b.t_s).sum::<f64>() / n;
    let mth = w.iter().map(|b| b.theta_a_rad).sum::<f64>() / n;
    let (stt, stth) = w.iter().fold((0.0, 0.0), |(a, c), b| {
        let dt = b.t_s - mt;
        (a + dt * dt, c + dt * (b.theta_a_rad - mth))
    });
    if !(stt > 0.0) {
        return None;
    }
    let slope = stth / stt;
    let dev = w
        .iter()
        .map(|b| (b.theta_a_rad - mth - slope * (b.t_s - mt)).abs())
        .fold(0.0, f64::max);
    Some((slope, dev))
}

/// max − min of `f` over a window.
pub(super) fn range(w: &[Block], f: impl Fn(&Block) -> f64) -> f64 {
    let (lo, hi) = w
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), b| {
            (lo.min(f(b)), hi.max(f(b)))
        });
    hi - lo
}

/// Mean of `f` over a window (NaN when empty).
pub(super) fn mean(w: &[Block], f: impl Fn(&Block) -> f64) -> f64 {
    if w.is_empty() {
        return f64::NAN;
    }
    w.iter().map(f).sum::<f64>() / w.len() as f64
}

/// A block's tick: its index + 1.
pub(super) fn tick(b: &Block) -> u32 {
    b.index.saturating_add(1)
}

/// One block as a request sample.
pub(super) fn sample_of(b: &Block) -> Sample {
    Sample {
        tick: tick(b),
        theta_a_urad: micro(b.theta_a_rad),
        torque_unm: micro(b.torque_nm),
        torque_ref_unm: micro(b.torque_nm),
    }
}

/// Mean of a window as a sample stamped at its last block.
pub(super) fn window_sample(w: &[Block]) -> Option<Sample> {
    let last = w.last()?;
    let th = mean(w, |b| b.theta_a_rad);
    let t = mean(w, |b| b.torque_nm);
    Some(Sample {
        tick: tick(last),
        theta_a_urad: micro(th),
        torque_unm: micro(t),
        torque_ref_unm: micro(t),
    })
}
