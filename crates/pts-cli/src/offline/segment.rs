//! Phases 3–5: the segment's end (unloading), its end point (the settled hold), the static
//! points on the path, and the request the controller would have built; the loop over every
//! contact of a trace.

use grasp::config::HISTORY;
use grasp::estimate::{to_micro as micro, EstimateRequest, Sample, PATH_CAPACITY};
use heapless::Vec;
use pts::Model;

use super::blocks::{
    line_in_time, mean, median, range, sample_of, tick, window_sample, MovingMean,
};
use super::contact::{back_date, detect_rise, knee_point, knee_theta};
use super::{Block, OfflineConfig, OfflineError, Segment};

/// Finds the next contact at or after block `from` and builds its request.
/// `block_s` is the block length [`make_blocks`](super::make_blocks) returned; `quantum_rad`
/// the encoder step (0 when unknown).
pub fn find_contact<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    blocks: &[Block],
    block_s: f64,
    quantum_rad: f64,
    from: usize,
) -> Result<Segment, OfflineError> {
    let wf = cfg.free_window.clamp(4, 64);
    let wq = cfg.static_window.clamp(4, 64);
    let conf = cfg.confirm.clamp(1, 64);
    let n = blocks.len();
    if n < from.saturating_add(wf + conf + wq) {
        return Err(if from == 0 {
            OfflineError::TooShort
        } else {
            OfflineError::NoContact
        });
    }
    let t_free = |th: f64| -> Option<f64> {
        model
            .free_from_theta_a(R::try_from_f64(th)?)
            .ok()
            .map(|c| c.ta.to_f64())
    };
    // 1-2. Arm on free motion, detect the residual's rise, fit the knee.
    let d = detect_rise(cfg, blocks, from, wf, conf)?;
    let (det, offset, sigma) = (d.detect, d.offset_nm, d.sigma_nm);
    let (k_lo, th_lo, mut theta_c) = knee_theta(cfg, blocks, from, &d, conf);
    let (mut knee, mut kb, mut ta_c) = knee_point(blocks, from, k_lo, theta_c, offset, &t_free)?;

    // 3. Segment end.
    let thband = cfg.static_band_rad + 1.5 * quantum_rad.max(0.0);
    let half = wq / 2;
    let next = segment_end(cfg, blocks, det, ta_c, thband, half);

    // 4. End point.
    let tband = cfg.torque_band_nm.max(6.0 * sigma);
    let end = end_window(cfg, blocks, det, next, wq, thband, tband)?;
    let end_w = blocks.get(end.0..end.1).ok_or(OfflineError::NotSettled)?;
    let end_s = window_sample(end_w).ok_or(OfflineError::NotSettled)?;
    let t_end = f64::from(end_s.torque_unm) * 1e-6;
    let th_end = f64::from(end_s.theta_a_urad) * 1e-6;
    let dta = t_end - ta_c;
    if !(dta >= cfg.min_step_nm) {
        return Err(OfflineError::StepTooSmall {
            delta_ta_unm: micro(dta),
        });
    }

    // 5. Quasi-static windows on the path between the detection and the end window.
    let margin = (0.05 * dta).max(2e-3);
    let path = PathWindows {
        cfg,
        blocks,
        wq,
        thband,
        tband,
        ta_c_nm: ta_c,
        t_end_nm: t_end,
        margin_nm: margin,
        end_lo: end.0,
    };
    // With static (or quasi-static) points on the path — a controller that held the torque
    // after the contact, a slow ramp — back-date like the controller does: the parabola
    // θa(T_a) through the first one, the one nearest mid-step and the end meets the shifted
    // free-motion curve at the contact. This survives an impact that carries θa past the
    // contact (the residual's rise then starts late). Otherwise the seat is the knee itself
    // (δ_seat = 0, so the estimator's back-dating returns it) and the second point the
    // quasi-static window nearest mid-step, else the midpoint of the chord to the end.
    let mut static_seats: Option<(usize, usize)> = None;
    if let Some((k1, t1, th1)) = path.first_above(f64::NEG_INFINITY, det + 1) {
        if let Some((k2, tb, thb)) = path.nearest(0.5 * (t1 + t_end), t1 + margin, k1 + wq) {
            if let Some((th, _)) = back_date(&t_free, offset, (t1, th1), (tb, thb), (t_end, th_end))
            {
                if th >= th_lo - 0.03 {
                    theta_c = th;
                    (knee, kb, ta_c) = knee_point(blocks, from, k_lo, theta_c, offset, &t_free)?;
                    static_seats = Some((k1, k2));
                }
            }
        }
    }
    let dta = t_end - ta_c;
    if !(dta >= cfg.min_step_nm) {
        return Err(OfflineError::StepTooSmall {
            delta_ta_unm: micro(dta),
        });
    }
    let want = 0.5 * (ta_c + t_end);
    let contact = Sample {
        tick: tick(&kb),
        theta_a_urad: micro(theta_c),
        torque_unm: micro(ta_c),
        torque_ref_unm: micro(ta_c),
    };
    let mid = Sample {
        tick: contact.tick.saturating_add(1),
        theta_a_urad: micro(0.5 * (theta_c + th_end)),
        torque_unm: micro(want),
        torque_ref_unm: micro(want),
    };
    let (seat_s, seat2_s, static_pts) = match static_seats {
        Some((k1, k2)) => {
            let s1 = blocks.get(k1..k1 + wq).and_then(window_sample);
            let s2 = blocks.get(k2..k2 + wq).and_then(window_sample);
            match (s1, s2) {
                (Some(a), Some(b)) => (a, b, true),
                _ => (contact, mid, false),
            }
        }
        None => {
            let s2 = path
                .nearest(want, ta_c + margin, det + 1)
                .and_then(|(k2, _, _)| blocks.get(k2..k2 + wq))
                .and_then(window_sample);
            match s2 {
                Some(b) => (contact, b, false),
                None => (contact, mid, false),
            }
        }
    };
    let request = build_request(
        cfg,
        blocks,
        (from, det, end.1),
        block_s,
        [contact, seat_s, seat2_s, end_s],
        dta,
    );
    Ok(Segment {
        knee,
        detect: det,
        end,
        next,
        contact_t_s: kb.t_s,
        theta_a_c_rad: theta_c,
        ta_c_nm: ta_c,
        offset_nm: offset,
        end_point: (th_end, t_end),
        static_path_points: static_pts,
        request,
    })
}

/// Median of the torque over the static window centred on block `j` (`half` blocks each
/// side): no electrical spike counts. NaN outside the blocks.
fn torque_median(blocks: &[Block], j: usize, half: usize) -> f64 {
    let lo = j.saturating_sub(half);
    let hi = (j + half + 1).min(blocks.len());
    blocks
        .get(lo..hi)
        .and_then(|w| median(w.iter().map(|b| b.torque_nm)))
        .unwrap_or(f64::NAN)
}

/// Phase 3: the first block from the detection `det` where the median torque falls well below
/// its running maximum (by the larger of `unload_drop_nm` and 30 % of the rise above `ta_c`)
/// while the finger no longer advances (by more than `thband` over `half` blocks); the number
/// of blocks when it never does.
pub fn segment_end(
    cfg: &OfflineConfig,
    blocks: &[Block],
    det: usize,
    ta_c: f64,
    thband: f64,
    half: usize,
) -> usize {
    let n = blocks.len();
    let theta_at = |j: usize| blocks.get(j.min(n - 1)).map_or(f64::NAN, |b| b.theta_a_rad);
    let mut tmax = f64::NEG_INFINITY;
    for j in det..n {
        let t = torque_median(blocks, j, half);
        if t > tmax {
            tmax = t;
        }
        let drop = cfg.unload_drop_nm.max(0.3 * (tmax - ta_c));
        if t < tmax - drop && !(theta_at(j + half) > theta_at(j) + thband) {
            return j;
        }
    }
    n
}

/// Phase 4: the end window `(lo, hi)` — the last window of `wq` blocks before `next` where
/// the finger is static or creeps quasi-statically (θa linear in time within `thband`, slow),
/// with a torque that moves only as the path allows (within `tband`, not a stiction plateau,
/// not the start of an unload). Never static (an undamped oscillation): the late half of the
/// steady-torque hold, at least `wq` blocks long by the torque's median over a window (which
/// spends half a window leaving the step: a 0.2 s hold at 4 ms blocks reads about 150 ms),
/// else [`OfflineError::NotSettled`].
pub fn end_window(
    cfg: &OfflineConfig,
    blocks: &[Block],
    det: usize,
    next: usize,
    wq: usize,
    thband: f64,
    tband: f64,
) -> Result<(usize, usize), OfflineError> {
    let end_ok = |w: &[Block]| -> bool {
        let Some((slope, dev)) = line_in_time(w) else {
            return false;
        };
        let dth = range(w, |b| b.theta_a_rad);
        dev <= thband
            && slope.abs() <= cfg.end_speed_rad_s
            && range(w, |b| b.torque_nm) <= tband + cfg.plateau_stiffness_nm_per_rad * dth
    };
    let mut j = next;
    while j >= det + wq {
        if blocks.get(j - wq..j).is_some_and(end_ok) {
            return Ok((j - wq, j));
        }
        j -= 1;
    }
    let half = wq / 2;
    let last = next.checked_sub(1).ok_or(OfflineError::NotSettled)?;
    let t_end = torque_median(blocks, last, half);
    let mut s = last;
    while s > det && (torque_median(blocks, s - 1, half) - t_end).abs() <= tband {
        s -= 1;
    }
    let len = last + 1 - s;
    if len < wq {
        return Err(OfflineError::NotSettled);
    }
    Ok((s + len / 2, last + 1))
}

/// Phase 5: the quasi-static windows of `wq` blocks on the path, before the end window.
struct PathWindows<'a> {
    cfg: &'a OfflineConfig,
    blocks: &'a [Block],
    wq: usize,
    thband: f64,
    tband: f64,
    /// T_a,c at the knee (N·m): a window below it (by 0.1 N·m) is not on the path.
    ta_c_nm: f64,
    /// T_a of the end point (N·m).
    t_end_nm: f64,
    /// A window must end this far below the end point (N·m).
    margin_nm: f64,
    /// First block of the end window.
    end_lo: usize,
}

impl PathWindows<'_> {
    /// (mean T_a, mean θa) of a window that is a static hold or a quasi-static stretch of the
    /// path (θa linear in time, T_a rising no faster than the path allows), between the
    /// contact and the end point.
    fn quasi(&self, w: &[Block]) -> Option<(f64, f64)> {
        let (slope, dev) = line_in_time(w)?;
        if dev > self.thband {
            return None;
        }
        let dtq = range(w, |b| b.torque_nm);
        let dth = slope * (w.last()?.t_s - w.first()?.t_s);
        let static_hold = dtq <= self.tband && dth.abs() <= self.thband;
        let on_path = dth > 0.0 && dtq <= self.cfg.plateau_stiffness_nm_per_rad * dth;
        if !(static_hold || on_path) {
            return None;
        }
        let t = mean(w, |b| b.torque_nm);
        (t > self.ta_c_nm - 0.1 && t < self.t_end_nm - self.margin_nm)
            .then(|| (t, mean(w, |b| b.theta_a_rad)))
    }

    /// The first quasi-static window from block `k0` with a torque above `lo_t`:
    /// (first block, T_a, θa).
    fn first_above(&self, lo_t: f64, k0: usize) -> Option<(usize, f64, f64)> {
        let mut k = k0;
        while k + self.wq <= self.end_lo {
            if let Some(w) = self.blocks.get(k..k + self.wq) {
                if let Some((t, th)) = self.quasi(w) {
                    if t > lo_t {
                        return Some((k, t, th));
                    }
                }
            }
            k += 1;
        }
        None
    }

    /// The quasi-static window from block `k0` with a torque above `lo_t` nearest `want`
    /// (the first of equals): (first block, T_a, θa).
    fn nearest(&self, want: f64, lo_t: f64, k0: usize) -> Option<(usize, f64, f64)> {
        let mut best: Option<(usize, f64, f64)> = None;
        let mut k = k0;
        while k + self.wq <= self.end_lo {
            if let Some((t, th)) = self.blocks.get(k..k + self.wq).and_then(|w| self.quasi(w)) {
                if t > lo_t && best.is_none_or(|b| (t - want).abs() < (b.1 - want).abs()) {
                    best = Some((k, t, th));
                }
            }
            k += 1;
        }
        best
    }
}

/// The request as the controller builds it: the free-motion history up to the detection
/// (`pre`, from `from`), the blocks after it up to the end window's last (`hi`) decimated into
/// [`PATH_CAPACITY`], the four points (contact, seat, seat2, end) and ΔT_a.
fn build_request(
    cfg: &OfflineConfig,
    blocks: &[Block],
    (from, det, hi): (usize, usize, usize),
    block_s: f64,
    [contact, seat, seat2, end]: [Sample; 4],
    dta: f64,
) -> EstimateRequest {
    let mut pre: Vec<Sample, HISTORY> = Vec::new();
    let pre_lo = (det + 1).saturating_sub(HISTORY).max(from);
    for b in blocks.get(pre_lo..=det).unwrap_or(&[]) {
        let _ = pre.push(sample_of(b));
    }
    // The path: only the rows in which the crank moved. While it stands still (a stiction
    // plateau, the hold) the transmission's friction is anywhere in its stiction band, not
    // the sliding friction of the approach that the fit's offset carries; a block that
    // straddles a plateau and a slip would average the two.
    let path_blocks = blocks.get(det + 1..hi).unwrap_or(&[]);
    let moving = || path_blocks.iter().filter(|b| b.moving_rows > 0);
    let n_moving = moving().count();
    let mut stride = 1usize;
    while n_moving.div_ceil(stride) > PATH_CAPACITY {
        stride *= 2;
    }
    let mut path: Vec<Sample, PATH_CAPACITY> = Vec::new();
    let mut group = MovingMean::default();
    for (i, b) in moving().enumerate() {
        group.add(b);
        if (i + 1) % stride == 0 || i + 1 == n_moving {
            if let Some(s) = group.take() {
                let _ = path.push(s);
            }
        }
    }
    let dt_ns = (block_s * 1e9 + 0.5) as u32;
    EstimateRequest {
        contact,
        seat,
        seat2,
        end,
        pre,
        path,
        sample_ticks: 1,
        path_stride: stride as u32,
        delta_ta_cmd_unm: micro(dta),
        detect_k_unm_per_rad: micro(cfg.detect_stiffness_nm_per_rad),
        estimator: cfg.estimator,
        dt_ns: dt_ns.max(1),
    }
}

/// The path of a request rebuilt from the blocks for a drive identified on this recording
/// (its inertia and viscous term, [`DriveId`](super::DriveId)): the quasi-static torque of
/// each moving block after the contact block `knee`, T_a − inertia·θ̈a − viscous·θ̇a, kept only
/// while the crank turns in the loading direction (θ̇a > 0). Contact and drive friction both
/// resist the motion: on a swing back (a heavy drive oscillating on the contact, a bounce)
/// they change sign, and those samples lie off the loading path by twice the friction, which
/// no constant offset carries. With the inertia removed here, from the continuous record of
/// blocks, the oscillation about the path is on it, the swing up with its turning points
/// (whose inertial torques have opposite signs, so an inertia error largely cancels): the
/// request is for a fit told no inertia and no envelope. The samples are handed in order of
/// θa (the fit's bins run from the contact to the last sample), stamped with consecutive
/// ticks after the contact's; `pre` keeps the approach up to the contact. `half_width` is the
/// half-width (blocks) of the local quartic that gives θ̇a and θ̈a
/// ([`poly_speed_accel`](super::drive::poly_speed_accel)). `None` unless the
/// crank swings back after the contact by more than `min_swing_rad` (block means; −∞
/// rebuilds every path): below that the fit's own envelope keeps the whole path and the
/// request stays as it is.
pub fn loading_path(
    req: &EstimateRequest,
    blocks: &[Block],
    knee: usize,
    hi: usize,
    (inertia_kgm2, viscous_nm_s_per_rad): (f64, f64),
    half_width: usize,
    min_swing_rad: f64,
) -> Option<EstimateRequest> {
    let after = blocks.get(knee + 1..hi.min(blocks.len()))?;
    let (_, swing) = after
        .iter()
        .fold((f64::NEG_INFINITY, 0.0f64), |(top, sw), b| {
            let top = top.max(b.theta_a_rad);
            (top, sw.max(top - b.theta_a_rad))
        });
    if !(swing > min_swing_rad) {
        return None;
    }
    let kin = |k: usize| super::drive::poly_speed_accel(blocks, k, half_width);
    // (θa, quasi-static T_a) of each usable block, in time order.
    let mut pts: std::vec::Vec<(f64, f64)> = std::vec::Vec::new();
    for (k, b, dir) in moving_after_contact(blocks, knee, hi) {
        if dir != Some(core::cmp::Ordering::Greater) {
            continue;
        }
        // The record's last blocks have no centred difference: their raw torque would carry
        // the whole inertial torque, far off the path on a crank still swinging.
        let Some((w, acc)) = kin(k) else {
            continue;
        };
        let t = b.moving_torque_nm - inertia_kgm2 * acc - viscous_nm_s_per_rad * w.max(0.0);
        if t.is_finite() && b.moving_theta_a_rad.is_finite() {
            pts.push((b.moving_theta_a_rad, t));
        }
    }
    let mut stride = 1usize;
    while pts.len().div_ceil(stride) > PATH_CAPACITY {
        stride *= 2;
    }
    let mut groups: std::vec::Vec<(f64, f64)> = pts
        .chunks(stride)
        .map(|c| {
            let n = c.len() as f64;
            (
                c.iter().map(|x| x.0).sum::<f64>() / n,
                c.iter().map(|x| x.1).sum::<f64>() / n,
            )
        })
        .collect();
    groups.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = req.clone();
    let kt = req.contact.tick;
    out.pre.retain(|s| s.tick <= kt);
    out.path.clear();
    for (i, (th, t)) in groups.into_iter().enumerate() {
        let tm = micro(t);
        let _ = out.path.push(Sample {
            tick: kt.saturating_add(1 + i as u32),
            theta_a_urad: micro(th),
            torque_unm: tm,
            torque_ref_unm: tm,
        });
    }
    out.path_stride = stride as u32;
    Some(out)
}

/// The blocks after the contact block `knee` (up to `hi`) in which the crank moved, each with
/// its index and the direction it turned in across its neighbours (θa of the next block
/// against the previous: `Greater` loads the contact); the first and last blocks, which lack
/// a neighbour, are left out.
fn moving_after_contact(
    blocks: &[Block],
    knee: usize,
    hi: usize,
) -> impl Iterator<Item = (usize, &Block, Option<core::cmp::Ordering>)> {
    (knee + 1..hi.min(blocks.len())).filter_map(move |k| {
        let b = blocks.get(k).filter(|b| b.moving_rows > 0)?;
        let p = blocks.get(k.checked_sub(1)?)?;
        let n = blocks.get(k + 1)?;
        Some((k, b, super::angle_order(n.theta_a_rad, p.theta_a_rad)))
    })
}

/// The least and greatest of `values` (±∞ reversed when there are none).
fn span(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
        (l.min(v), h.max(v))
    })
}

/// The hysteresis of the contact path (N·m, with its standard error): how far the quasi-static
/// torque of the blocks that swing back lies below the loading path at the same θa. Each
/// moving block after the contact block `knee` (up to `hi`) gives T_a − inertia·θ̈a −
/// viscous·θ̇a; the blocks turning in the loading direction are fitted with a quadratic in θa
/// (the loading path), and the gap is the mean of their residuals minus the mean of the
/// swinging-back blocks' residuals, inside the θa span the loading blocks cover. Dry friction,
/// at the drive or at the object, resists the motion both ways and opens the gap by twice
/// its torque; an oscillation about the path on a frictionless contact leaves it at zero (an
/// inertia error acts alike on both halves of a swing). `None` with fewer than 4 blocks
/// either way.
pub fn path_hysteresis(
    blocks: &[Block],
    knee: usize,
    hi: usize,
    (inertia_kgm2, viscous_nm_s_per_rad): (f64, f64),
    half_width: usize,
) -> Option<(f64, f64)> {
    let mut fwd: std::vec::Vec<(f64, f64)> = std::vec::Vec::new();
    let mut back: std::vec::Vec<(f64, f64)> = std::vec::Vec::new();
    for (k, b, dir) in moving_after_contact(blocks, knee, hi) {
        let Some((w, acc)) = super::drive::poly_speed_accel(blocks, k, half_width) else {
            continue;
        };
        let t = b.moving_torque_nm - inertia_kgm2 * acc - viscous_nm_s_per_rad * w;
        let th = b.moving_theta_a_rad;
        if !(t.is_finite() && th.is_finite()) {
            continue;
        }
        match dir {
            Some(core::cmp::Ordering::Greater) => fwd.push((th, t)),
            Some(core::cmp::Ordering::Less) => back.push((th, t)),
            _ => {}
        }
    }
    if fwd.len() < 4 || back.len() < 4 {
        return None;
    }
    let (lo, hi_th) = span(fwd.iter().map(|p| p.0));
    // The loading path T = c0 + c1 x + c2 x², x = θa − mid (centred for conditioning).
    let mid = 0.5 * (lo + hi_th);
    let c = crate::linalg::polyfit(fwd.iter().map(|&(th, t)| (th - mid, t)), 2)?;
    let [c0, c1, c2] = c[..] else { return None };
    let eval = |th: f64| {
        let x = th - mid;
        c0 + c1 * x + c2 * x * x
    };
    let rf: std::vec::Vec<f64> = fwd.iter().map(|p| p.1 - eval(p.0)).collect();
    let rb: std::vec::Vec<f64> = back
        .iter()
        .filter(|p| p.0 >= lo && p.0 <= hi_th)
        .map(|p| p.1 - eval(p.0))
        .collect();
    if rb.len() < 4 {
        return None;
    }
    let stats = |r: &[f64]| {
        let n = r.len() as f64;
        let m = r.iter().sum::<f64>() / n;
        let v = r.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
        (m, v / n)
    };
    let (mf, vf) = stats(&rf);
    let (mb, vb) = stats(&rb);
    Some((mf - mb, (vf + vb).sqrt()))
}

/// The effective inertia at the crank while the finger presses on its contact, with its
/// standard error and the viscous term that goes with it, identified on the contact path
/// itself. The finger's own links move differently on a contact than in free motion, so the
/// approach's inertia is off by their share (about a tenth of a light drive's). Each moving
/// block after the contact block `knee` (up to `hi`) whose local quartic (half-width
/// `half_width` blocks, [`poly_speed_accel`](super::drive::poly_speed_accel)) no longer
/// reaches back to the impact, and whose θa lies at or above `theta_from_rad` (on the object:
/// a swing back off it follows the free motion, another function of θa), gives a row of
/// T_a = p(θa) + J·θ̈a + b·θ̇a + F·sgn θ̇a, p a cubic in θa (the quasi-static path), b a
/// viscous term, F a dry friction: an oscillation on the contact, whose θ̈a no function of θa
/// can follow, is what determines J. The viscous term b is the drive's plus the contact's
/// own damping (a soft object's, the pad's), which no approach sees. `None` with fewer than
/// [`CONTACT_INERTIA_MIN_BLOCKS`] rows or regressors that are not independent (a path
/// loaded without swinging cannot tell J from the path's curvature).
pub fn contact_inertia(
    blocks: &[Block],
    knee: usize,
    hi: usize,
    theta_from_rad: f64,
    half_width: usize,
) -> Option<ContactDynamics> {
    let mut pts: std::vec::Vec<(f64, f64, f64, f64, f64)> = std::vec::Vec::new();
    for (k, b, dir) in moving_after_contact(blocks, knee + half_width, hi) {
        let sign = match dir {
            Some(core::cmp::Ordering::Greater) => 1.0,
            Some(core::cmp::Ordering::Less) => -1.0,
            _ => continue,
        };
        let Some((w, acc)) = super::drive::poly_speed_accel(blocks, k, half_width) else {
            continue;
        };
        let (th, t) = (b.moving_theta_a_rad, b.moving_torque_nm);
        if th >= theta_from_rad && [th, t, w, acc].iter().all(|v| v.is_finite()) {
            pts.push((th, t, w, acc, sign));
        }
    }
    if pts.len() < CONTACT_INERTIA_MIN_BLOCKS {
        return None;
    }
    let (lo, hi_th) = span(pts.iter().map(|p| p.0));
    let (mid, half_span) = (0.5 * (lo + hi_th), 0.5 * (hi_th - lo));
    if !(half_span > 0.0) {
        return None;
    }
    let rows: std::vec::Vec<(std::vec::Vec<f64>, f64)> = pts
        .iter()
        .map(|&(th, t, w, acc, sign)| {
            let x = (th - mid) / half_span;
            (std::vec![1.0, x, x * x, x * x * x, acc, w, sign], t)
        })
        .collect();
    let fit = crate::linalg::least_squares(&rows, 7)?;
    let j = *fit.coef.get(4)?;
    let sigma = fit.std_error(4)?;
    let b = *fit.coef.get(5)?;
    [j, sigma, b]
        .iter()
        .all(|v| v.is_finite())
        .then_some(ContactDynamics {
            inertia_kgm2: j,
            sigma_inertia_kgm2: sigma,
            viscous_nm_s_per_rad: b,
        })
}

/// The dynamics of the crank on its contact ([`contact_inertia`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactDynamics {
    /// Effective inertia at the crank (kg·m²).
    pub inertia_kgm2: f64,
    /// Its standard error (kg·m²).
    pub sigma_inertia_kgm2: f64,
    /// Viscous term at the crank on the contact (N·m·s/rad): the drive's and the contact's.
    pub viscous_nm_s_per_rad: f64,
}

/// Fewest blocks [`contact_inertia`] fits its seven terms to.
pub const CONTACT_INERTIA_MIN_BLOCKS: usize = 16;

/// Every contact in the blocks, in order: calls `each` with each result (a contact's
/// [`Segment`], or the error that ended the search; the first `NoContact`/`NoFreeMotion`
/// after a contact is not reported). Returns the number of segments found.
pub fn for_each_contact<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    blocks: &[Block],
    block_s: f64,
    quantum_rad: f64,
    mut each: impl FnMut(Result<&Segment, OfflineError>),
) -> usize {
    let mut from = 0usize;
    let mut found = 0usize;
    while from < blocks.len() {
        match find_contact(model, cfg, blocks, block_s, quantum_rad, from) {
            Ok(seg) => {
                found += 1;
                each(Ok(&seg));
                from = seg.next.max(seg.end.1).max(from + 1);
            }
            Err(OfflineError::NoContact | OfflineError::NoFreeMotion | OfflineError::TooShort)
                if found > 0 =>
            {
                break;
            }
            Err(e) => {
                each(Err(e));
                // A refused contact: go on after its detection if there was one.
                match e {
                    OfflineError::StepTooSmall { .. } | OfflineError::NotSettled => {
                        // Skip past this contact's rise.
                        from = skip_contact(blocks, from).unwrap_or(blocks.len());
                    }
                    _ => break,
                }
            }
        }
    }
    found
}

/// After a refused contact: the first block after `from` where the torque is back below the
/// level it had at `from`'s free motion... approximated as the first block where θa decreases
/// for good (the finger opened). `None` when it never does.
fn skip_contact(blocks: &[Block], from: usize) -> Option<usize> {
    let mut peak = f64::NEG_INFINITY;
    let mut peak_i = from;
    for (i, b) in blocks.iter().enumerate().skip(from) {
        if b.theta_a_rad > peak {
            peak = b.theta_a_rad;
            peak_i = i;
        } else if peak - b.theta_a_rad > 0.01 {
            return Some(i.max(peak_i + 1));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    const CFG: OfflineConfig = OfflineConfig::DEFAULT;

    fn blocks(
        th: impl Fn(usize) -> f64,
        t: impl Fn(usize) -> f64,
        n: usize,
    ) -> std::vec::Vec<Block> {
        (0..n)
            .map(|k| Block {
                index: k as u32,
                t_s: 0.004 * k as f64,
                theta_a_rad: th(k),
                torque_nm: t(k),
                resid_nm: 0.0,
                first_row: k as u32,
                ..Block::default()
            })
            .collect()
    }

    /// A block whose four rows all moved, at mean θa `th` (rad) and T_a `tq` (N·m).
    fn moving_block(i: usize, t: f64, th: f64, tq: f64) -> Block {
        Block {
            index: i as u32,
            t_s: t,
            theta_a_rad: th,
            torque_nm: tq,
            moving_rows: 4,
            moving_theta_a_rad: th,
            moving_torque_nm: tq,
            ..Block::default()
        }
    }

    #[test]
    fn the_path_carries_the_moving_rows_only() {
        // Blocks 0..20; from the detection (block 4) on, every third block stuck (no moving
        // row), the others moving with a torque 0.05 N·m below their all-row mean.
        let mut b = blocks(|k| -0.2 + 1e-4 * k as f64, |k| 0.4 + 0.01 * k as f64, 20);
        for (k, x) in b.iter_mut().enumerate() {
            if k % 3 != 0 {
                x.moving_rows = 2;
                x.moving_theta_a_rad = x.theta_a_rad;
                x.moving_torque_nm = x.torque_nm - 0.05;
            }
        }
        let pts = [Sample::ZERO; 4];
        let req = build_request(&CFG, &b, (0, 4, 20), 0.004, pts, 0.3);
        let want: std::vec::Vec<(u32, i32)> = (5..20)
            .filter(|k| k % 3 != 0)
            .map(|k| (k as u32 + 1, micro(0.4 + 0.01 * k as f64 - 0.05)))
            .collect();
        let got: std::vec::Vec<(u32, i32)> =
            req.path.iter().map(|s| (s.tick, s.torque_unm)).collect();
        assert_eq!(got, want);
    }

    #[test]
    fn a_loading_path_is_the_swing_up_with_the_inertia_removed() {
        // A crank oscillating (20 mrad, 6 Hz) on a contact of 7 N·m/rad with an inertia of
        // 5e-3 kg·m² and 0.02 N·m of friction that resists the motion: the measured torque is
        // K (θ − θ0) + J θ̈ + F sgn θ̇. Recorded for 130 blocks (the record ends on a swing
        // up, where the last blocks have no centred acceleration) and for 150 (on a swing
        // back).
        let (k, j, f, w) = (7.0, 5e-3, 0.02, 2.0 * core::f64::consts::PI * 6.0);
        let th = |t: f64| -0.2 + 0.02 * (w * t).sin();
        for n in [130, 150] {
            let b: std::vec::Vec<Block> = (0..n)
                .map(|i| {
                    let t = 0.004 * i as f64;
                    let acc = -w * w * 0.02 * (w * t).sin();
                    let v = w * 0.02 * (w * t).cos();
                    let tq = k * (th(t) + 0.2) + j * acc + f * v.signum();
                    moving_block(i, t, th(t), tq)
                })
                .collect();
            let pts = [Sample::ZERO; 4];
            let req = build_request(&CFG, &b, (0, 1, n), 0.004, pts, 0.3);
            let out = loading_path(&req, &b, 1, n, (j, 0.0), 2, 0.03).expect("a 40 mrad swing");
            assert!(out.path.len() > 35, "{n} blocks: {}", out.path.len());
            let mut last = i32::MIN;
            for s in &out.path {
                // In order of θa, on the loading side of the path (friction +F), the inertial
                // torque (up to 0.14 N·m here) removed to within the differences' error.
                assert!(s.theta_a_urad >= last);
                last = s.theta_a_urad;
                let want = k * (f64::from(s.theta_a_urad) * 1e-6 + 0.2) + f;
                assert!(
                    (f64::from(s.torque_unm) * 1e-6 - want).abs() < 0.01,
                    "{n} blocks: {s:?} vs {want}"
                );
            }
            // No swing back beyond the limit: the request stays as it is.
            assert!(loading_path(&req, &b, 1, n, (j, 0.0), 2, 0.05).is_none());
        }
    }

    #[test]
    fn the_hysteresis_of_the_path_is_twice_its_dry_friction() {
        // The oscillator above (7 N·m/rad, 5e-3 kg·m², 6 Hz, 20 mrad) drifting 10 mrad/s onto
        // the contact, with dry friction F resisting the motion: T = K (θ − θ0) + J θ̈ + F sgn θ̇.
        let (k, j, w) = (7.0, 5e-3, 2.0 * core::f64::consts::PI * 6.0);
        let run = |f: f64| {
            let b: std::vec::Vec<Block> = (0..150)
                .map(|i| {
                    let t = 0.004 * i as f64;
                    let th = -0.2 + 0.01 * t + 0.02 * (w * t).sin();
                    let acc = -w * w * 0.02 * (w * t).sin();
                    let v = 0.01 + w * 0.02 * (w * t).cos();
                    let tq = k * (th + 0.2) + j * acc + f * v.signum();
                    moving_block(i, t, th, tq)
                })
                .collect();
            path_hysteresis(&b, 1, 150, (j, 0.0), 3).expect("swings both ways")
        };
        for f in [0.01, 0.02, 0.05] {
            let (gap, se) = run(f);
            assert!((gap - 2.0 * f).abs() < 0.1 * f, "F {f}: gap {gap} ± {se}");
            assert!(gap > 3.0 * se, "F {f}: gap {gap} ± {se}");
        }
        // Frictionless: the swing back lies on the loading path.
        let (gap, se) = run(0.0);
        assert!(gap.abs() < 2e-3, "gap {gap} ± {se}");
        // Never swinging back: nothing to compare.
        let mono: std::vec::Vec<Block> =
            blocks(|k| -0.2 + 1e-4 * k as f64, |k| 0.4 + 0.01 * k as f64, 60)
                .into_iter()
                .map(|b| moving_block(b.index as usize, b.t_s, b.theta_a_rad, b.torque_nm))
                .collect();
        assert!(path_hysteresis(&mono, 1, 60, (0.0, 0.0), 3).is_none());
    }

    #[test]
    fn the_contact_path_gives_back_the_inertia_it_carries() {
        // A decaying 12 Hz, 15 mrad ring about a path that stiffens (T = K x + K₂ x², x the
        // travel past the contact at −0.2 rad), loaded at 40 mrad/s, with inertia J and
        // viscous term b: T = path(θ) + J θ̈ + b θ̇. The ring dips up to 5 mrad below the
        // contact, where the finger is off the object and the torque follows the free motion
        // (a constant 0.35 N·m here), which the rows read must leave out.
        let (k, k2, b) = (6.0, 40.0, 0.004);
        let (w, lam, amp) = (2.0 * core::f64::consts::PI * 12.0, 2.0, 0.015);
        let run = |j: f64| {
            let blk: std::vec::Vec<Block> = (0..200)
                .map(|i| {
                    let t = 0.004 * i as f64;
                    let e = (-lam * t).exp();
                    let (sn, cs) = (w * t).sin_cos();
                    let x = 0.04 * t - 0.005 + amp * e * sn;
                    let v = 0.04 + amp * e * (w * cs - lam * sn);
                    let acc = amp * e * ((lam * lam - w * w) * sn - 2.0 * lam * w * cs);
                    let path = if x > 0.0 {
                        0.35 + k * x + k2 * x * x
                    } else {
                        0.35
                    };
                    let tq = path + j * acc + b * v;
                    let th = -0.2 + x;
                    moving_block(i, t, th, tq)
                })
                .collect();
            (
                contact_inertia(&blk, 1, 200, -0.2 + 3e-3, 3),
                contact_inertia(&blk, 1, 200, f64::NEG_INFINITY, 3),
            )
        };
        for j in [5e-4, 5.3e-4, 5e-3] {
            let (on, all) = run(j);
            let d = on.expect("the ring determines J");
            let (got, se) = (d.inertia_kgm2, d.sigma_inertia_kgm2);
            assert!((got - j).abs() < 0.01 * j, "J {j}: {got} ± {se}");
            assert!(se < 0.01 * j, "J {j}: σ {se}");
            // ... and the damping that rings down with it.
            assert!(
                (d.viscous_nm_s_per_rad - b).abs() < 0.05 * b,
                "J {j}: b {} against {b}",
                d.viscous_nm_s_per_rad
            );
            // The rows off the object, read as if on it, bias a light drive's J by more than
            // the 1 % (a heavy one's ring torque dwarfs the kink).
            let biased = all.expect("fitted").inertia_kgm2;
            if j < 1e-3 {
                assert!((biased - j).abs() > 0.01 * j, "J {j}: all rows {biased}");
            }
        }
        // A path loaded without ringing: J is not told apart from the path's curvature.
        let mono: std::vec::Vec<Block> = blocks(
            |i| -0.2 + 1e-3 * i as f64,
            |i| 0.35 + 6.0 * 1e-3 * i as f64,
            60,
        )
        .into_iter()
        .map(|b| moving_block(b.index as usize, b.t_s, b.theta_a_rad, b.torque_nm))
        .collect();
        assert!(contact_inertia(&mono, 1, 60, -0.2, 3)
            .is_none_or(|d| d.sigma_inertia_kgm2 > 0.03 * d.inertia_kgm2.abs()));
    }

    #[test]
    fn the_segment_ends_where_the_median_torque_unloads() {
        // Rise to 1 N·m over 50 blocks after the detection at 10, hold, unload at 150.
        let b = blocks(
            |k| -0.2 + 1e-4 * k.min(60) as f64,
            |k| match k {
                0..60 => 0.4 + 0.01 * k as f64,
                60..150 => 1.0,
                _ => 0.6,
            },
            250,
        );
        assert_eq!(segment_end(&CFG, &b, 10, 0.5, 1e-4, 12), 150);
        // Never unloading: the segment runs to the end of the trace.
        let hold = blocks(|_| -0.2, |_| 1.0, 120);
        assert_eq!(segment_end(&CFG, &hold, 10, 0.5, 1e-4, 12), 120);
    }

    #[test]
    fn the_end_point_is_the_last_static_window_before_the_segment_end() {
        let b = blocks(
            |k| -0.2 + 1e-4 * k.min(60) as f64,
            |k| if k < 60 { 0.4 + 0.01 * k as f64 } else { 1.0 },
            150,
        );
        assert_eq!(
            end_window(&CFG, &b, 10, 150, 25, 1e-4, 4e-3),
            Ok((125, 150))
        );
    }

    #[test]
    fn never_static_ends_on_the_late_half_of_the_steady_torque_hold() {
        // θa rings (1 mrad) for ever: no static window; the torque is steady from the start.
        let b = blocks(|k| -0.2 + 1e-3 * (0.9 * k as f64).sin(), |_| 1.0, 110);
        assert_eq!(end_window(&CFG, &b, 10, 110, 25, 1e-4, 4e-3), Ok((60, 110)));
        // A hold of 40 blocks (less than two windows, as a 0.2 s hold reads): its late half.
        assert_eq!(end_window(&CFG, &b, 70, 110, 25, 1e-4, 4e-3), Ok((90, 110)));
        // A hold shorter than one window has not settled.
        assert_eq!(
            end_window(&CFG, &b, 90, 110, 25, 1e-4, 4e-3),
            Err(OfflineError::NotSettled)
        );
    }
}
