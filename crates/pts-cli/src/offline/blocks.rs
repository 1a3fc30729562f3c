//! Phase 0: the trace averaged into blocks (the controller's samples), and the window
//! statistics the other phases share.

use grasp::estimate::{to_micro as micro, Sample};
use pts::Model;

use super::{Block, OfflineConfig, OfflineError, TraceSample, MIN_RATE_HZ, OUTLIER_RAD};

/// How close (a fraction of a block) a row may lie before a block boundary and still be
/// taken as on it, in the later block. A 1 kHz recording puts every fourth row on a 4 ms
/// boundary, and the rounding of its time difference (its last bits, which a shift of the
/// time origin or a column in ms changes) would otherwise decide which block takes it. A
/// thousandth of a block (4 µs) is above the rounding of times up to 1e10 s and below any
/// row spacing a recording has.
pub const BOUNDARY_TOL: f64 = 1e-3;

/// Averages the trace into blocks (into `scratch`); returns how many were written and the
/// block length used (s). Rows must be in non-decreasing time; equal times are fine. A row
/// within [`BOUNDARY_TOL`] of a block before a boundary counts in the later block.
pub fn make_blocks<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    rows: &[TraceSample],
    scratch: &mut [Block],
) -> Result<(usize, f64), OfflineError> {
    let block = block_length(cfg, rows, scratch.len())?;
    let Some(first) = rows.first() else {
        return Err(OfflineError::TooShort);
    };
    let mut n = 0usize;
    let mut cur: Option<Acc> = None;
    let mut flush = |c: Acc, n: &mut usize| {
        let k = f64::from(c.count);
        let th = c.theta / k;
        let resid = model
            .free_from_theta_a(R::from_f64(th))
            .map(|f| c.torque / k - f.ta.to_f64())
            .unwrap_or(f64::NAN);
        let km = f64::from(c.moving);
        let moving_mean = |s: f64| if c.moving > 0 { s / km } else { f64::NAN };
        if let Some(slot) = scratch.get_mut(*n) {
            *slot = Block {
                index: c.index,
                t_s: c.t / k,
                theta_a_rad: th,
                torque_nm: c.torque / k,
                resid_nm: resid,
                first_row: c.first_row,
                moving_rows: c.moving,
                moving_theta_a_rad: moving_mean(c.moving_theta),
                moving_torque_nm: moving_mean(c.moving_torque),
            };
            *n += 1;
        }
    };
    let mut prev_theta = first.theta_a_rad;
    let mut prev_t = first.t_s;
    for (i, r) in rows.iter().enumerate() {
        let idx = ((r.t_s - first.t_s) / block + BOUNDARY_TOL) as u32;
        if cur.is_some_and(|c| c.index != idx) {
            if let Some(c) = cur.take() {
                flush(c, &mut n);
            }
        }
        let c = cur.get_or_insert(Acc {
            index: idx,
            first_row: i as u32,
            ..Acc::default()
        });
        c.t += r.t_s;
        c.theta += r.theta_a_rad;
        c.torque += r.torque_nm;
        c.count = c.count.saturating_add(1);
        // A crank creeping slower than a settled one by less than half a count stands still:
        // an unquantised recording shows a stuck contact or drive as a drift of µrad, which
        // an encoder would not see.
        let step = (r.theta_a_rad - prev_theta).abs();
        if i > 0
            && (step >= 0.5 * cfg.encoder_count_rad
                || step > cfg.end_speed_rad_s * (r.t_s - prev_t))
        {
            c.moving = c.moving.saturating_add(1);
            c.moving_theta += r.theta_a_rad;
            c.moving_torque += r.torque_nm;
        }
        prev_theta = r.theta_a_rad;
        prev_t = r.t_s;
    }
    if let Some(c) = cur {
        flush(c, &mut n);
    }
    Ok((n, block))
}

/// The block length (s) the trace is averaged into, for at most `capacity` blocks, once its
/// rows pass the checks every recording must: finite, in non-decreasing time, no lone θa
/// outlier, recorded at [`MIN_RATE_HZ`] or more (of the median row spacing).
pub fn block_length(
    cfg: &OfflineConfig,
    rows: &[TraceSample],
    capacity: usize,
) -> Result<f64, OfflineError> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if !(positive(cfg.block_s) && positive(cfg.encoder_count_rad)) || capacity == 0 {
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
    // The rate the rows were recorded at: of their median spacing, so rows a recording lost
    // (a gap) do not lower it.
    if let Some(spacing) = median_spacing(rows.iter().map(|r| r.t_s)) {
        let rate = 1.0 / spacing;
        if rate < MIN_RATE_HZ * 0.98 {
            return Err(OfflineError::SampleRateTooLow {
                rate_hz: rate as u32,
            });
        }
    }
    let cap = capacity as f64;
    let block = if span / cfg.block_s > cap - 1.0 {
        span / (cap - 1.0)
    } else {
        cfg.block_s
    };
    if !(block > 0.0) {
        return Err(OfflineError::TooShort);
    }
    Ok(block)
}

/// The median time between consecutive rows with distinct times (s), of the rows' times in
/// order; `None` without two.
pub fn median_spacing(times_s: impl IntoIterator<Item = f64>) -> Option<f64> {
    let mut prev = None;
    let mut d: Vec<f64> = times_s
        .into_iter()
        .filter_map(|t| prev.replace(t).map(|p| t - p))
        .filter(|d| *d > 0.0)
        .collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied()
}

/// Sums over the rows of one block.
#[derive(Clone, Copy, Default)]
struct Acc {
    index: u32,
    first_row: u32,
    count: u32,
    t: f64,
    theta: f64,
    torque: f64,
    /// Rows in which θa changed, and their sums.
    moving: u32,
    moving_theta: f64,
    moving_torque: f64,
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

/// The mean over the moving rows of consecutive blocks, weighted by their counts: one path
/// sample stamped at the last block added.
#[derive(Clone, Copy, Default)]
pub(super) struct MovingMean {
    rows: f64,
    theta: f64,
    torque: f64,
    tick: u32,
}

impl MovingMean {
    /// Adds a block's moving rows (a block without any adds nothing).
    pub(super) fn add(&mut self, b: &Block) {
        if b.moving_rows > 0 {
            let k = f64::from(b.moving_rows);
            self.rows += k;
            self.theta += k * b.moving_theta_a_rad;
            self.torque += k * b.moving_torque_nm;
            self.tick = tick(b);
        }
    }

    /// The sample so far (`None` when no row moved), and starts a new one.
    pub(super) fn take(&mut self) -> Option<Sample> {
        let m = core::mem::take(self);
        (m.rows > 0.0).then(|| {
            let t = micro(m.torque / m.rows);
            Sample {
                tick: m.tick,
                theta_a_urad: micro(m.theta / m.rows),
                torque_unm: t,
                torque_ref_unm: t,
            }
        })
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// 1 kHz rows: θa stuck for 10 ms while the torque climbs through the stiction band, a
    /// slip of 2 mrad, stuck again (drifting by 1 µrad a row, 1 mrad/s, as an unquantised
    /// record of a stuck crank does); then crawling one row in two.
    fn stick_slip() -> std::vec::Vec<TraceSample> {
        (0..40)
            .map(|i| {
                let theta = match i {
                    0..10 => -0.3,
                    10..20 => -0.298 + 1e-6 * (i - 10) as f64,
                    _ => -0.298 + 1e-4 * ((i - 19) / 2) as f64,
                };
                TraceSample {
                    t_s: 0.001 * i as f64,
                    theta_a_rad: theta,
                    torque_nm: 0.4 + 0.001 * i as f64,
                }
            })
            .collect()
    }

    #[test]
    fn moving_means_keep_only_the_rows_in_which_the_crank_moved() {
        let model = Model::<f64>::paper().unwrap();
        let cfg = OfflineConfig::DEFAULT;
        let mut scratch = [Block::default(); 16];
        let rows = stick_slip();
        let (n, block_s) = make_blocks(&model, &cfg, &rows, &mut scratch).unwrap();
        assert!((block_s - cfg.block_s).abs() < 1e-12);
        let b = &scratch[..n];
        // Blocks of 4 rows: 0..4 and 4..8 stuck, 8..12 holds the slip at row 10.
        assert_eq!((b[0].moving_rows, b[1].moving_rows), (0, 0));
        assert!(b[0].moving_torque_nm.is_nan() && b[1].moving_theta_a_rad.is_nan());
        // The drift after the slip (rows 11..20) is slower than a settled crank: still.
        assert_eq!(b[2].moving_rows, 1);
        assert_eq!((b[3].moving_rows, b[4].moving_rows), (0, 0));
        assert_eq!(b[2].moving_theta_a_rad, -0.298);
        assert!((b[2].moving_torque_nm - 0.41).abs() < 1e-12);
        // The plain means still average every row.
        assert!((b[2].torque_nm - 0.4095).abs() < 1e-12);
        // Crawling (rows 21, 23, … move): two of each block's four rows.
        assert!(b[6..9].iter().all(|k| k.moving_rows == 2), "{:?}", &b[6..9]);
    }

    /// A quantised 250 Hz recording of a crank creeping one encoder count per row
    /// (0.008 rad/s, slower than a settled crank): every count is a move, as at any rate.
    #[test]
    fn a_whole_count_is_a_move_at_any_sample_rate() {
        let model = Model::<f64>::paper().unwrap();
        let cfg = OfflineConfig::DEFAULT;
        let q = cfg.encoder_count_rad;
        let paper = pts::config::FingerFile::paper().rad_per_count();
        assert!(
            (q - paper).abs() < 1e-15 * paper,
            "the default is the paper finger's count"
        );
        let rows: std::vec::Vec<TraceSample> = (0..40)
            .map(|i| TraceSample {
                t_s: 0.004 * i as f64,
                theta_a_rad: -0.3 + q * i as f64,
                torque_nm: 0.4,
            })
            .collect();
        assert!(q / 0.004 < cfg.end_speed_rad_s);
        let mut scratch = [Block::default(); 64];
        let (n, _) = make_blocks(&model, &cfg, &rows, &mut scratch).unwrap();
        // One row per 4 ms block; the first has no row before it.
        assert!(
            scratch[1..n].iter().all(|b| b.moving_rows == 1),
            "{:?}",
            &scratch[..n]
        );
        let bad = OfflineConfig {
            encoder_count_rad: 0.0,
            ..cfg
        };
        assert_eq!(
            make_blocks(&model, &bad, &rows, &mut scratch),
            Err(OfflineError::BadConfig)
        );
    }

    #[test]
    fn a_moving_mean_weights_blocks_by_their_moving_rows() {
        let block = |index: u32, rows: u32, th: f64, t: f64| Block {
            index,
            moving_rows: rows,
            moving_theta_a_rad: th,
            moving_torque_nm: t,
            ..Block::default()
        };
        let mut m = MovingMean::default();
        m.add(&block(3, 3, -0.2, 0.5));
        m.add(&block(4, 0, f64::NAN, f64::NAN));
        m.add(&block(5, 1, -0.1, 0.9));
        let s = m.take().unwrap();
        assert_eq!(s.tick, 6);
        assert_eq!(s.theta_a_urad, -175_000);
        assert_eq!(s.torque_unm, 600_000);
        // Taken: the next sample starts empty.
        assert_eq!(m.take(), None);
    }
}
