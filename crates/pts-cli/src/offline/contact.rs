//! Phases 1–2: arming on free motion, detecting the rise of the free-motion residual (a
//! stiction stall is not a contact), the knee where the rise meets the shifted free-motion
//! curve, its back-dating through static points on the path, and the contact point on the
//! dynamics-corrected residual once the drive is identified.

use heapless::Vec;
use pts::{Model, PtsError};

use super::blocks::{mean, median};
use super::drive::{kinematics, DriveId, KIN_SPAN};
use super::{Block, OfflineConfig, OfflineError, Segment};

/// A free-motion window: θa advanced by ≥ arm, residual flat. Returns (offset, σ).
pub fn free_window(cfg: &OfflineConfig, w: &[Block]) -> Option<(f64, f64)> {
    let (first, last) = (w.first()?, w.last()?);
    if w.iter().any(|b| b.resid_nm.is_nan()) {
        return None;
    }
    if !(last.theta_a_rad - first.theta_a_rad >= cfg.arm_rad) {
        return None;
    }
    // θa must advance through the window (no stall in the middle of it).
    let h = w.len() / 2;
    let (a, b) = w.split_at(h);
    let mid = b.first()?.theta_a_rad;
    let travel = last.theta_a_rad - first.theta_a_rad;
    if !(mid - first.theta_a_rad > 0.2 * travel && last.theta_a_rad - mid > 0.2 * travel) {
        return None;
    }
    let off = median(w.iter().map(|b| b.resid_nm))?;
    // σ from successive differences: a trend (a slow contact rise) must not pass for noise.
    let mad = median(w.windows(2).map(|p| match p {
        [x, y] => (y.resid_nm - x.resid_nm).abs(),
        _ => f64::NAN,
    }))?;
    let sigma = 1.4826 * mad / core::f64::consts::SQRT_2;
    let ma = median(a.iter().map(|b| b.resid_nm))?;
    let mb = median(b.iter().map(|b| b.resid_nm))?;
    // Flat: the residual's change between the halves is noise, or far less than a contact
    // adds per radian (≥ K_c,proximal − K_free ≈ 2 N·m/rad).
    let dth = mean(b, |x| x.theta_a_rad) - mean(a, |x| x.theta_a_rad);
    if !((mb - ma).abs() <= 2.0 * sigma + cfg.free_slope_nm_per_rad * dth.abs()) {
        return None;
    }
    Some((off, sigma))
}

/// A confirmed rise of the free-motion residual above the approach's offset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Detection {
    /// First block of the confirmed run above the threshold.
    pub first_above: usize,
    /// Block where the run was confirmed.
    pub detect: usize,
    /// The approach offset (median residual, N·m) of the baseline armed a full window before
    /// the rise began.
    pub offset_nm: f64,
    /// σ of the residual in that baseline window (N·m).
    pub sigma_nm: f64,
}

/// Phases 1–2: arm on free motion from block `from` (a window of `wf` blocks), then detect the
/// residual staying above the baseline by the threshold for `conf` blocks in a row. The
/// baseline of a detection is the one armed a full window before the rise began (the latest
/// ones see its start); a rise that resumes free motion is a stall and is skipped.
pub fn detect_rise(
    cfg: &OfflineConfig,
    blocks: &[Block],
    from: usize,
    wf: usize,
    conf: usize,
) -> Result<Detection, OfflineError> {
    let n = blocks.len();
    let mut ring = [(0usize, 0.0f64, 0.0f64); 64];
    let mut armed: Option<(f64, f64)> = None;
    let mut ever_armed = false;
    let mut run = 0usize;
    let mut i = from + wf;
    while i < n {
        if run == 0 {
            if let Some(fw) = blocks.get(i - wf..i).and_then(|w| free_window(cfg, w)) {
                armed = Some(fw);
                ever_armed = true;
                if let Some(slot) = ring.get_mut(i % 64) {
                    *slot = (i, fw.0, fw.1);
                }
            }
        }
        if armed.is_none() {
            i += 1;
            continue;
        }
        // Compare with a baseline from a window at least half a window old (a slow rise
        // must not drag it along).
        let lag = wf / 2;
        let Some((off, sigma)) = ring
            .iter()
            .filter(|e| e.0 > from && e.0 + lag <= i)
            .max_by_key(|e| e.0)
            .map(|e| (e.1, e.2))
        else {
            i += 1;
            continue;
        };
        let thr = cfg.detect_excess_nm.max(8.0 * sigma);
        let r = blocks.get(i).map_or(f64::NAN, |b| b.resid_nm);
        if r - off > thr {
            run += 1;
            if run >= conf {
                let first = i + 1 - conf;
                // A stall in free motion (stiction) also raises the residual at constant θa:
                // a contact only if the finger, once it moves again, does not go back onto
                // the free-motion curve.
                if let Some(resume) = resumes_free(cfg, blocks, i, off, thr, wf) {
                    armed = None;
                    run = 0;
                    i = resume;
                    continue;
                }
                let early = ring
                    .iter()
                    .filter(|e| e.0 > from && e.0 + wf <= first)
                    .max_by_key(|e| e.0)
                    .map_or((off, sigma), |e| (e.1, e.2));
                return Ok(Detection {
                    first_above: first,
                    detect: i,
                    offset_nm: early.0,
                    sigma_nm: early.1,
                });
            }
        } else {
            run = 0;
        }
        i += 1;
    }
    Err(if ever_armed {
        OfflineError::NoContact
    } else {
        OfflineError::NoFreeMotion
    })
}

/// The knee's θa,c: the rise of the residual, extrapolated back to the shifted free-motion
/// curve (a line through the residual excess against θa while θa still advances, up to
/// `4 conf` blocks past the detection). Returns (the last block at or below the low
/// threshold before the rise, its θa, θa,c), θa,c within [θa of that block − 5 mrad, the last
/// θa fitted]; without a usable line, θa of that block.
pub fn knee_theta(
    cfg: &OfflineConfig,
    blocks: &[Block],
    from: usize,
    d: &Detection,
    conf: usize,
) -> (usize, f64, f64) {
    let n = blocks.len();
    let (offset, sigma) = (d.offset_nm, d.sigma_nm);
    let thr = cfg.detect_excess_nm.max(8.0 * sigma);
    let low = (3.0 * sigma).max(0.25 * cfg.detect_excess_nm);
    let excess = |k: usize| blocks.get(k).map_or(f64::NAN, |b| b.resid_nm - offset);
    let mut k_lo = d.first_above.saturating_sub(1);
    while k_lo > from && !(excess(k_lo) <= low) {
        k_lo -= 1;
    }
    let th_lo = blocks.get(k_lo).map_or(f64::NAN, |b| b.theta_a_rad);
    let (mut sx, mut sy, mut sxx, mut sxy, mut cnt) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let mut th_prev = th_lo;
    let mut th_hi = th_lo;
    for k in k_lo + 1..n.min(d.detect + 4 * conf + 1) {
        let Some(b) = blocks.get(k) else { break };
        let e = excess(k);
        if super::angle_order(b.theta_a_rad, th_prev) == Some(core::cmp::Ordering::Less)
            || e > 4.0 * thr
        {
            break;
        }
        th_prev = b.theta_a_rad;
        if e >= low {
            // θa taken from th_lo: the spread of angles a stuck crank holds is then the
            // rounding of its block means, not a difference of two large squares.
            let x = b.theta_a_rad - th_lo;
            sx += x;
            sy += e;
            sxx += x * x;
            sxy += x * e;
            cnt += 1.0;
            th_hi = b.theta_a_rad;
        }
    }
    let mut theta_c = th_lo;
    if cnt >= 3.0 {
        let (mx, my) = (sx / cnt, sy / cnt);
        let vxx = sxx / cnt - mx * mx;
        let slope = (sxy / cnt - mx * my) / vxx;
        // Angles that spread by no more than the rounding of block means give no line: its
        // slope would be the rounding's draw.
        if vxx > super::SAME_ANGLE_RAD * super::SAME_ANGLE_RAD && slope > 0.0 {
            let z = th_lo + mx - my / slope;
            if z.is_finite() {
                theta_c = z.clamp(th_lo - 5e-3, th_hi);
            }
        }
    }
    (k_lo, th_lo, theta_c)
}

/// The knee block for θa,c: the last one at or below θa,c from `k_lo` back (its tick closes
/// the free-motion data), and T_a,c on the free-motion curve shifted by the offset the
/// estimator will measure: the mean residual of the `FIT_SAMPLES` blocks up to the knee (so
/// that its back-dating through this point returns it; `offset` when there is none).
pub fn knee_point(
    blocks: &[Block],
    from: usize,
    k_lo: usize,
    theta_c: f64,
    offset: f64,
    t_free: &dyn Fn(f64) -> Option<f64>,
) -> Result<(usize, Block, f64), OfflineError> {
    let mut knee = k_lo;
    while knee > from && blocks.get(knee).is_some_and(|b| b.theta_a_rad > theta_c) {
        knee -= 1;
    }
    let kb = *blocks.get(knee).ok_or(OfflineError::TooShort)?;
    let lo = (knee + 1)
        .saturating_sub(grasp::estimate::FIT_SAMPLES)
        .max(from);
    let est_off = blocks
        .get(lo..=knee)
        .map(|w| mean(w, |b| b.resid_nm))
        .filter(|v| v.is_finite())
        .unwrap_or(offset);
    let ta_c = t_free(theta_c).ok_or(OfflineError::Model(PtsError::OutOfRange))? + est_off;
    Ok((knee, kb, ta_c))
}

/// After a rise of the residual detected at `at`: the block where the finger is back in free
/// motion (θa advancing with the residual within `thr` of `off`) before the torque falls,
/// if it is: then the rise was a stall, not a contact.
fn resumes_free(
    cfg: &OfflineConfig,
    blocks: &[Block],
    at: usize,
    off: f64,
    thr: f64,
    wf: usize,
) -> Option<usize> {
    let t_at = blocks.get(at)?.torque_nm;
    let mut j = at + wf;
    while let Some(w) = blocks.get(j - wf..j) {
        let last = w.last()?;
        if last.torque_nm < t_at - cfg.unload_drop_nm {
            return None;
        }
        if let Some((o, _)) = free_window(cfg, w) {
            if (o - off).abs() <= 0.5 * thr {
                return Some(j);
            }
        }
        j += 1;
        if j > at + 16 * wf {
            return None;
        }
    }
    None
}

/// Where the parabola θa(T_a) through three points (T, θ) on the path meets the free-motion
/// curve shifted by `offset`: secant from the first point's torque downwards, as
/// `estimate::contact_point_model` does. (θa,c rad, T_a,c N·m), or `None` when implausible.
pub fn back_date(
    t_free: &dyn Fn(f64) -> Option<f64>,
    offset: f64,
    p1: (f64, f64),
    pb: (f64, f64),
    p2: (f64, f64),
) -> Option<(f64, f64)> {
    let ((t1, th1), (tb, thb), (t2, th2)) = (p1, pb, p2);
    let gap = grasp::estimate::MIN_STATIC_GAP_NM;
    if !(tb - t1 > gap && t2 - tb > gap) {
        return None;
    }
    let s1b = (thb - th1) / (tb - t1);
    let sb2 = (th2 - thb) / (t2 - tb);
    let c2 = (sb2 - s1b) / (t2 - t1);
    let q = |t: f64| th1 + s1b * (t - t1) + c2 * (t - t1) * (t - tb);
    grasp::estimate::meet_free_curve(&q, t_free, offset, (t1, th1), 16)
}

/// The contact point on the dynamics-corrected residual: with the drive identified
/// ([`identify_drive`]), e = T_a − T_free(θa) − offset − viscous·θ̇a − inertia·θ̈a is noise in
/// free motion and (K_c − K_free)(θa − θa,c) once the object is touched, whatever the crank's
/// speed, its ringing before or its bounce after the impact. θa,c is the hinge of that line
/// (least squares over a 0.1 mrad grid, the middle of a run of equal losses, reaching back
/// from the detection 15 mrad, or to where the crank was when the detection's latency began,
/// whichever is further), fitted on the
/// moving blocks from a free-motion window before the knee up to 8 mrad past it. The latency
/// is the confirmation run ([`OfflineConfig::confirm`]) and the triangle's width: a crank
/// reaching the object at 1 rad/s travels 4 mrad per 4 ms block, and a fixed 15 mrad would
/// put the contact on the window's edge.
///
/// θ̈a comes from a second difference across ±`KIN_SPAN` blocks, which is the true θ̈a
/// averaged under a triangle of that half-width (`SPAN_WEIGHTS`). So the rest of the balance
/// goes through the same triangle (the residual, and the hinge it is compared with): every
/// term then describes one window, and the torque noise is averaged over its 7 blocks.
/// After the detection, the hinge reads no window that holds a torque step (a rise between
/// two blocks above a quarter of the request's ΔT_a): across a step that balance
/// depends on where in its period a recording's torque acts, which no recording says.
/// Returns (θa,c rad, T_a,c = T_free(θa,c) + offset N·m, trace time of θa,c s).
///
/// [`identify_drive`]: super::identify_drive
pub fn refine_contact<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    blocks: &[Block],
    seg: &Segment,
    id: &DriveId,
    quantum_rad: f64,
) -> Option<(f64, f64, f64)> {
    let t_free = |th: f64| -> Option<f64> {
        model
            .free_from_theta_a(R::try_from_f64(th)?)
            .ok()
            .map(|c| c.ta.to_f64())
    };
    let wf = cfg.free_window.clamp(4, 64);
    let lo = seg.knee.saturating_sub(2 * wf).max(KIN_SPAN);
    let th_top = blocks.get(seg.detect)?.theta_a_rad.max(seg.theta_a_c_rad) + 8e-3;
    let latency = cfg.confirm + SPAN_WEIGHTS.len();
    let ta_detect = blocks.get(seg.detect)?.torque_nm;
    let dta = f64::from(seg.request.end.torque_unm) * 1e-6 - ta_detect;
    let thc = hinge_theta(
        blocks,
        lo,
        (seg.detect, latency),
        // Without a rise to the end there is no step to stop at.
        (
            th_top,
            if dta > 0.0 {
                STEP_JUMP_FRAC * dta
            } else {
                f64::INFINITY
            },
        ),
        id,
        quantum_rad,
        &t_free,
    )?;
    let ta_c = t_free(thc)? + id.offset_nm;
    let t_c = blocks
        .iter()
        .skip(lo)
        .find(|b| b.theta_a_rad >= thc)
        .map_or(seg.contact_t_s, |b| b.t_s);
    Some((thc, ta_c, t_c))
}

/// θa,c of [`refine_contact`]: the hinge of the smoothed residual over the moving blocks from
/// `lo` up to θa `th_top` (at most 200 blocks past `detect`, and up to the first window after
/// it in which the torque rises between two blocks by more than `jump_nm` N·m), on a 0.1 mrad
/// grid from the detection's θa back over 15 mrad or to the θa `latency` blocks before it,
/// whichever is further. Where neighbouring grid angles tie at the least loss
/// ([`LOSS_TIE_REL`]: no block lies between them), the middle of that run. `None` with fewer
/// than 8 blocks.
fn hinge_theta(
    blocks: &[Block],
    lo: usize,
    (detect, latency): (usize, usize),
    (th_top, jump_nm): (f64, f64),
    id: &DriveId,
    quantum_rad: f64,
    t_free: &dyn Fn(f64) -> Option<f64>,
) -> Option<f64> {
    let th_det = blocks.get(detect)?.theta_a_rad;
    let mut pts: Vec<Smoothed, 512> = Vec::new();
    let mut k = lo;
    while k + KIN_SPAN < blocks.len() && pts.len() < 512 {
        let b = blocks.get(k)?;
        k += 1;
        if k > detect && holds_torque_step(blocks, k - 1, jump_nm) {
            break;
        }
        if k > detect + 200 || b.theta_a_rad > th_top {
            if k > detect {
                break;
            }
            continue;
        }
        let Some(m) = kinematics(blocks, k - 1, quantum_rad) else {
            continue;
        };
        let Some(p) = smoothed(blocks, k - 1, t_free) else {
            continue;
        };
        let e = p.e
            - id.offset_nm
            - id.viscous_nm_s_per_rad * m.speed_rad_s
            - id.inertia_kgm2 * m.accel_rad_s2;
        if e.is_finite() {
            let _ = pts.push(Smoothed { e, ..p });
        }
    }
    if pts.len() < 8 {
        return None;
    }
    let scale = id.noise_nm.max(1e-4);
    // θa,c on a 0.1 mrad grid; the first of equals.
    let th_latency = blocks
        .get(detect.saturating_sub(latency))
        .map_or(th_det, |b| b.theta_a_rad);
    // (least loss, first and last grid angle of the run of grid points that tie with it).
    let mut best = (f64::INFINITY, th_det, th_det);
    let mut thc = (th_det - 15e-3).min(th_latency);
    let mut prev_tied = false;
    while thc <= th_det {
        let v = hinge_loss(&pts, thc, scale);
        let tied = (v - best.0).abs() <= LOSS_TIE_REL * v.abs();
        if v < best.0 && !tied {
            best = (v, thc, thc);
            prev_tied = true;
        } else if tied && prev_tied {
            best.2 = thc;
        } else {
            prev_tied = false;
        }
        thc += HINGE_STEP_RAD;
    }
    Some(0.5 * (best.1 + best.2))
}

/// Whether the torque rises by more than `jump_nm` (N·m) between two neighbouring blocks of
/// the window the balance of block `k` reads (±[`KIN_SPAN`] blocks).
fn holds_torque_step(blocks: &[Block], k: usize, jump_nm: f64) -> bool {
    let window = &blocks[k.saturating_sub(KIN_SPAN)..(k + KIN_SPAN + 1).min(blocks.len())];
    window
        .windows(2)
        .any(|w| w[1].torque_nm - w[0].torque_nm > jump_nm)
}

/// The share of ΔT_a by which the torque must rise between two blocks for [`refine_contact`]
/// to call it a step: a step's rise lands within one or two blocks, while a 0.05 s ramp
/// rises by 8 % of it per 4 ms block and is read as before.
const STEP_JUMP_FRAC: f64 = 0.25;

/// Grid step of the hinge angle in [`hinge_theta`] (rad).
const HINGE_STEP_RAD: f64 = 1e-4;

/// Relative difference within which two hinge losses are equal. Between two grid angles that
/// no block angle separates, the hinge's regressors differ by a multiple of the step column
/// and the losses are equal in exact arithmetic; in floating point they differ in the last
/// bits, and taking the smaller of them would let the rounding (a last-bit change of θa)
/// choose among the angles the data cannot tell apart.
const LOSS_TIE_REL: f64 = 1e-9;

/// The weights, for offsets −(s−1) … s−1 blocks, under which the second difference across ±s
/// blocks ([`KIN_SPAN`]) averages θ̈a: (s − |j|)/s², summing to 1.
const SPAN_WEIGHTS: [f64; 2 * KIN_SPAN - 1] = {
    let mut w = [0.0; 2 * KIN_SPAN - 1];
    let mut i = 0;
    while i < w.len() {
        let j = i.abs_diff(KIN_SPAN - 1);
        w[i] = (KIN_SPAN - j) as f64 / (KIN_SPAN * KIN_SPAN) as f64;
        i += 1;
    }
    w
};

/// One block seen through [`SPAN_WEIGHTS`]: the θa of the blocks under the triangle, and the
/// free-motion residual T_a − T_free(θa) averaged under it (N·m).
#[derive(Clone, Copy, Debug)]
struct Smoothed {
    theta_a_rad: [f64; 2 * KIN_SPAN - 1],
    e: f64,
}

/// Block `k` through the triangle; `None` near the ends or where T_free has no answer.
fn smoothed(blocks: &[Block], k: usize, t_free: &dyn Fn(f64) -> Option<f64>) -> Option<Smoothed> {
    let first = k.checked_sub(KIN_SPAN - 1)?;
    let w = blocks.get(first..first + SPAN_WEIGHTS.len())?;
    let mut th = [0.0; 2 * KIN_SPAN - 1];
    let mut e = 0.0;
    for ((b, wt), t) in w.iter().zip(SPAN_WEIGHTS).zip(th.iter_mut()) {
        *t = b.theta_a_rad;
        e += wt * (b.torque_nm - t_free(b.theta_a_rad)?);
    }
    Some(Smoothed { theta_a_rad: th, e })
}

/// The loss of a hinge at `thc` through the smoothed residuals: past θa,c the residual is
/// (K_c − K_free)(θa − θa,c) plus what the transmission's stiction holds once the crank
/// stops on the object (a step ≥ 0; without it that excess right after the contact drags the
/// hinge early), both seen through [`SPAN_WEIGHTS`] like the residual. Slope and step by
/// least squares (both ≥ 0), then a Huber loss at 3 `scale`: a lone spike must not move the
/// hinge.
fn hinge_loss(pts: &[Smoothed], thc: f64, scale: f64) -> f64 {
    let regressors = |p: &Smoothed| {
        p.theta_a_rad
            .iter()
            .zip(SPAN_WEIGHTS)
            .fold((0.0, 0.0), |(h, u), (&th, w)| {
                let past = th > thc;
                (h + w * (th - thc).max(0.0), u + if past { w } else { 0.0 })
            })
    };
    let (mut seh, mut shh, mut seu, mut shu, mut suu) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in pts.iter() {
        let (h, u) = regressors(p);
        let e = p.e;
        seh += e * h;
        shh += h * h;
        seu += e * u;
        shu += h * u;
        suu += u * u;
    }
    let det = shh * suu - shu * shu;
    let (mut sl, mut d) = if det > 1e-30 {
        ((seh * suu - seu * shu) / det, (seu * shh - seh * shu) / det)
    } else {
        (0.0, 0.0)
    };
    if d < 0.0 || sl < 0.0 {
        d = 0.0;
        sl = if shh > 0.0 { (seh / shh).max(0.0) } else { 0.0 };
    }
    pts.iter()
        .map(|p| {
            let (h, u) = regressors(p);
            let r = (p.e - sl * h - d * u).abs();
            if r <= 3.0 * scale {
                r * r
            } else {
                3.0 * scale * (2.0 * r - 3.0 * scale)
            }
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// θa advancing 0.1 mrad per 4 ms block; the free-motion residual flat at 0.05 N·m with
    /// a small deterministic scatter, rising by `k_c` N·m/rad past block `knee` (if any).
    fn trace(n: usize, knee: Option<usize>, k_c: f64, step: f64) -> std::vec::Vec<Block> {
        let th = |k: usize| -0.3 + step * k as f64;
        (0..n)
            .map(|k| {
                let noise = 2e-4 * (((k * 7919) % 13) as f64 / 13.0 - 0.5);
                let rise = knee.map_or(0.0, |c| k_c * (th(k) - th(c)).max(0.0));
                Block {
                    index: k as u32,
                    t_s: 0.004 * k as f64,
                    theta_a_rad: th(k),
                    torque_nm: 0.3 + 0.05 + rise + noise,
                    resid_nm: 0.05 + rise + noise,
                    first_row: k as u32,
                    ..Block::default()
                }
            })
            .collect()
    }

    const CFG: OfflineConfig = OfflineConfig::DEFAULT;

    #[test]
    fn free_motion_arms_with_the_median_residual_as_offset() {
        let b = trace(40, None, 0.0, 1e-4);
        let (off, sigma) = free_window(&CFG, &b[..25]).expect("free motion");
        assert!((off - 0.05).abs() < 1e-4, "offset {off}");
        assert!(sigma > 0.0 && sigma < 2e-4, "σ {sigma}");
        // A stall (θa still) is not free motion.
        let stall = trace(40, None, 0.0, 0.0);
        assert_eq!(free_window(&CFG, &stall[..25]), None);
    }

    #[test]
    fn detects_the_rise_after_the_knee_against_the_approach_offset() {
        let b = trace(200, Some(100), 10.0, 1e-4);
        let d = detect_rise(&CFG, &b, 0, 25, 5).expect("a contact");
        // 10 N·m/rad at 0.1 mrad per block crosses the 12 mN·m threshold 12 blocks after
        // the knee; confirmed 5 blocks later.
        assert!(d.first_above > 100 && d.first_above <= 115, "{d:?}");
        assert_eq!(d.detect, d.first_above + 4);
        assert!((d.offset_nm - 0.05).abs() < 1e-4, "{d:?}");
    }

    #[test]
    fn no_rise_is_no_contact_and_no_motion_never_arms() {
        let flat = trace(200, None, 0.0, 1e-4);
        assert_eq!(
            detect_rise(&CFG, &flat, 0, 25, 5),
            Err(OfflineError::NoContact)
        );
        let still = trace(200, None, 0.0, 0.0);
        assert_eq!(
            detect_rise(&CFG, &still, 0, 25, 5),
            Err(OfflineError::NoFreeMotion)
        );
    }

    #[test]
    fn the_knee_is_the_rise_extrapolated_back_to_the_offset() {
        let b = trace(200, Some(100), 10.0, 1e-4);
        let d = detect_rise(&CFG, &b, 0, 25, 5).expect("a contact");
        let (k_lo, th_lo, theta_c) = knee_theta(&CFG, &b, 0, &d, 5);
        // The last block still at the offset, and θa,c extrapolated behind it (not before
        // its θa − 5 mrad).
        assert!(k_lo < d.first_above, "{k_lo} {d:?}");
        assert!(
            theta_c >= th_lo - 5e-3 && theta_c <= th_lo,
            "{th_lo} {theta_c}"
        );
        let truth = b[100].theta_a_rad;
        // Within 2 blocks of travel (the scatter moves the line a little).
        assert!((theta_c - truth).abs() < 2e-4, "θa,c {theta_c} vs {truth}");
        // Its knee block is the last one at or below θa,c, T_a,c on the shifted curve.
        let t_free = |th: f64| Some(th + 1.0);
        let (knee, kb, ta_c) = knee_point(&b, 0, k_lo, theta_c, d.offset_nm, &t_free).unwrap();
        assert!(
            kb.theta_a_rad <= theta_c && b[knee + 1].theta_a_rad > theta_c,
            "{knee}"
        );
        assert!((ta_c - (theta_c + 1.0 + 0.05)).abs() < 2e-4, "T_a,c {ta_c}");
    }

    /// A crank that sticks on the object: past block 100 θa stands still while the torque
    /// rises. Its block means differ only in their last bits (how the rows' sum rounds), and
    /// no line through them can be drawn: θa,c is the last block at the offset, whichever
    /// way those bits fall.
    #[test]
    fn a_crank_stuck_on_the_object_gives_no_line_through_rounding() {
        let theta_c_for = |bits: f64| {
            let mut b = trace(200, None, 0.0, 1e-4);
            let stuck = b[100].theta_a_rad;
            for (k, blk) in b.iter_mut().enumerate().skip(100) {
                let wobble = bits * ((k * 31) % 5) as f64 - 2.0 * bits;
                blk.theta_a_rad = stuck + wobble;
                blk.resid_nm += 4e-3 * (k - 100) as f64;
                blk.torque_nm += 4e-3 * (k - 100) as f64;
            }
            let d = detect_rise(&CFG, &b, 0, 25, 5).expect("a contact");
            let (_, th_lo, theta_c) = knee_theta(&CFG, &b, 0, &d, 5);
            (th_lo, theta_c)
        };
        let exact = theta_c_for(0.0);
        assert_eq!(exact.1, exact.0, "{exact:?}");
        for bits in [1e-17, -1e-17, 3e-17, -3e-17] {
            let (th_lo, theta_c) = theta_c_for(bits);
            assert_eq!(theta_c, th_lo, "last bits {bits:e}");
            assert!(
                (theta_c - exact.1).abs() < 1e-15,
                "last bits {bits:e}: {theta_c}"
            );
        }
    }

    /// Blocks (4 ms, from 1 kHz rows) of a heavy crank (J = 5e-3 kg·m²) reaching the object at
    /// `v` rad/s at θa,c = −0.22 rad, t = 0.4 s (block 100), the contact a 6 N·m/rad spring:
    /// past θa,c the crank swings on it, θa = θa,c + (v/ω)·sin ω(t − t_c) with ω = √(K/J),
    /// while the drive holds T_free(θa), so T_a − T_free − J θ̈a = K (θa − θa,c) exactly.
    /// `noise` is added to each row's torque. Returns the blocks and the drive as identified.
    fn heavy_crank(v: f64, noise: impl FnMut() -> f64) -> (std::vec::Vec<Block>, DriveId) {
        heavy_crank_stepped(v, noise, None)
    }

    /// [`heavy_crank`] with a torque step `(t_s s, ΔT N·m, lead s)`: from t_s the drive holds
    /// T_free(θa) + ΔT and the crank swings about the spring's new rest, θa gains
    /// (ΔT/K)(1 − cos ω(t − t_s)); the recorded torque shows the step `lead` early, as a
    /// recording whose torque rows are not stamped where they act.
    fn heavy_crank_stepped(
        v: f64,
        mut noise: impl FnMut() -> f64,
        step: Option<(f64, f64, f64)>,
    ) -> (std::vec::Vec<Block>, DriveId) {
        let model = pts::Model::<f64>::paper().unwrap();
        let t_free = |th: f64| model.free_from_theta_a(th).unwrap().ta;
        let (j, k, th_c, t_c): (f64, f64, f64, f64) = (5e-3, 6.0, -0.22, 0.4);
        let w = (k / j).sqrt();
        let (t_s, dta, lead) = step.unwrap_or((f64::INFINITY, 0.0, 0.0));
        let theta = |t: f64| {
            if t < t_c {
                th_c + v * (t - t_c)
            } else if t < t_s {
                th_c + v / w * (w * (t - t_c)).sin()
            } else {
                th_c + v / w * (w * (t - t_c)).sin() + dta / k * (1.0 - (w * (t - t_s)).cos())
            }
        };
        let blocks = (0..150)
            .map(|b| {
                let (mut th, mut tq) = (0.0, 0.0);
                for i in 0..4 {
                    let t = 1e-3 * (4 * b + i) as f64;
                    let x = theta(t);
                    th += x / 4.0;
                    let held = if t >= t_s - lead { dta } else { 0.0 };
                    tq += (t_free(x) + held + noise()) / 4.0;
                }
                Block {
                    index: b as u32,
                    t_s: 1e-3 * (4 * b) as f64 + 1.5e-3,
                    theta_a_rad: th,
                    torque_nm: tq,
                    resid_nm: tq - t_free(th),
                    moving_rows: 4,
                    ..Block::default()
                }
            })
            .collect();
        let id = DriveId {
            inertia_kgm2: j,
            sigma_inertia_kgm2: 0.0,
            viscous_nm_s_per_rad: 0.0,
            sigma_viscous_nm_s_per_rad: 0.0,
            offset_nm: 0.0,
            sigma_offset_nm: 0.0,
            stiction_excess_nm: None,
            noise_nm: 2.5e-3,
            blocks: 100,
            accel_span_rad_s2: 0.0,
        };
        (blocks, id)
    }

    /// θa,c from [`hinge_theta`] on `blocks` detected `after` blocks past the contact block.
    fn hinge_of(blocks: &[Block], id: &DriveId, after: usize, latency: usize) -> f64 {
        hinge_of_with(blocks, id, after, latency, f64::INFINITY)
    }

    /// [`hinge_of`] with the torque rise between two blocks that ends the hinge's blocks.
    fn hinge_of_with(
        blocks: &[Block],
        id: &DriveId,
        after: usize,
        latency: usize,
        jump_nm: f64,
    ) -> f64 {
        let model = pts::Model::<f64>::paper().unwrap();
        let t_free = |th: f64| model.free_from_theta_a(th).ok().map(|c| c.ta);
        let detect = 100 + after;
        let top = blocks[detect].theta_a_rad + 8e-3;
        hinge_theta(
            blocks,
            detect - 40,
            (detect, latency),
            (top, jump_nm),
            id,
            1e-9,
            &t_free,
        )
        .unwrap()
    }

    /// The heavy crank at 0.9 rad/s (3.6 mrad per block) with 5 mN·m of torque noise per row
    /// (a fixed pseudo-random sequence per seed), detected three blocks after the contact. Over
    /// 32 seeds the hinge's RMS error stays within a third of a block's travel and its worst
    /// within one: the residual taken through the same triangle as θ̈a averages the torque
    /// noise over 7 blocks (RMS 0.96 mrad, worst 3.1, with the middle of the grid angles that
    /// tie between two block angles; the residual of the block alone gave RMS 2.0 mrad, worst
    /// 3.3, with the tie decided by rounding).
    #[test]
    fn the_hinge_of_a_heavy_crank_on_noisy_torque_stays_on_the_contact() {
        let (mut sum_sq, mut worst) = (0.0, 0.0f64);
        let seeds = 32u64;
        for seed in 0..seeds {
            // xorshift: uniform on ±√3·σ has σ 5 mN·m.
            let mut x = 0x9E37_79B9_7F4A_7C15u64 ^ (seed + 1).wrapping_mul(0xA076_1D64_78BD_642F);
            let noise = || {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                5e-3 * 3f64.sqrt() * (2.0 * (x >> 11) as f64 / (1u64 << 53) as f64 - 1.0)
            };
            let (blocks, id) = heavy_crank(0.9, noise);
            let thc = hinge_of(&blocks, &id, 3, 12);
            sum_sq += (thc + 0.22) * (thc + 0.22);
            worst = worst.max((thc + 0.22).abs());
        }
        let rms = (sum_sq / seeds as f64).sqrt();
        // A block's travel: 0.9 rad/s × 4 ms.
        let block = 3.6e-3;
        assert!(
            rms < block / 3.0 && worst < block,
            "θa,c error RMS {rms:.5} rad, worst {worst:.5} rad"
        );
    }

    /// A faster crank (1.5 rad/s, 6 mrad per block), noise-free, confirmed six blocks after
    /// the contact: the detection is 33 mrad past θa,c, so a search reaching back a fixed
    /// 15 mrad ends before the contact (it answered near its edge, 19 mrad late). Reaching back
    /// over the detection's latency in blocks, it lands on the contact (0.75 mrad late).
    #[test]
    fn a_fast_crank_is_searched_back_over_the_detection_latency() {
        let (blocks, id) = heavy_crank(1.5, || 0.0);
        let thc = hinge_of(&blocks, &id, 6, 12);
        assert!((thc + 0.22).abs() < 1e-3, "θa,c {thc:.5} rad for -0.22");
        let fixed = hinge_of(&blocks, &id, 6, 0);
        assert!(
            fixed > -0.22 + 2e-3,
            "a 15 mrad search: θa,c {fixed:.5} rad"
        );
    }

    /// A torque step of 0.5 N·m 12, 20 or 30 ms after the contact of the heavy crank
    /// (detected three blocks after it), its torque rows stamped where they act, one row early
    /// or one row late. Across a step the second difference of block means is no longer the
    /// triangle-averaged θ̈a that the residual's weights assume, so a hinge that reads the
    /// step's windows lands up to 6.7 mrad off; one that stops at the first window holding
    /// the step is never further off, and 20 or 30 ms after the contact it is within a third
    /// of a block's travel.
    #[test]
    fn the_hinge_stops_before_a_torque_step() {
        let block = 3.6e-3;
        let (mut worst_read, mut worst_cut) = (0.0f64, 0.0f64);
        for lead in [0.0, 1e-3, -1e-3] {
            for after_s in [0.012, 0.02, 0.03] {
                let step = Some((0.4 + after_s, 0.5, lead));
                let (blocks, id) = heavy_crank_stepped(0.9, || 0.0, step);
                let read = (hinge_of(&blocks, &id, 3, 12) + 0.22).abs();
                let cut = (hinge_of_with(&blocks, &id, 3, 12, STEP_JUMP_FRAC * 0.5) + 0.22).abs();
                assert!(
                    cut <= read + 1e-9,
                    "step {after_s} s after, lead {lead} s: {cut:.5} rad off, reading it {read:.5}"
                );
                worst_read = worst_read.max(read);
                if after_s > 0.015 {
                    worst_cut = worst_cut.max(cut);
                }
            }
        }
        assert!(
            worst_cut < block / 3.0 && worst_read > 2.0 * block / 3.0,
            "stopping at the step: worst {worst_cut:.5} rad; reading it: worst {worst_read:.5} rad"
        );
    }
}
