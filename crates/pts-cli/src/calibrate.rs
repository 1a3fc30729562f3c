//! Identification of a finger's springs and drive from a calibration sweep (`pts calibrate`).
//!
//! The sweep closes and opens the free finger slowly (see [`crate::sweep`]); an optional
//! second recording closes it onto a fixed post at a known θ1 on the proximal phalanx. The
//! fit is a Gauss–Newton least squares on the measured torque, in f64, with the statics of
//! `docs/MODEL.md` (free motion; with the post, θ1 held):
//!
//! T_meas = L(θa) · (1 closing | ρ opening) + F_c·sgn(θ̇a) + b·θ̇a + J·θ̈a + T_off
//!
//! where L is the spring torque, ρ the product of the driving and back-driven efficiencies,
//! F_c the Coulomb friction, b the viscous term and J the effective inertia at the crank.
//! σ comes from the covariance of the fit scaled by the residual and by its correlation.
//!
//! What a free sweep cannot separate: θ0,1 does not enter the free-motion torque at all (θ1
//! is not measured; only θa − θa,rest is); K1 and K2 enter almost only through the series
//! compliance 1/K1 + x2²/K2, and θ0,2 only through the slow change of x2. The touch against
//! the post adds K2′/x2² after contact and the torque at which θ1 reaches the post, which
//! separate K1, K2 and θ0,1. The torque scale (kt·η·current gain) is not identifiable from
//! either: springs and friction come out in the units of the measured torque, which is what
//! the estimator needs (its k2 does not change when all torques scale together).

use crate::sweep::{DistalPost, Post};
use crate::trace::TraceRow;
use pts::config::FingerFile;
use pts::{Finger, Model};
use serde_json::{json, Value};
use std::fmt;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// Why a sweep was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum CalibError {
    /// Fewer moving samples than the fit needs, or a recording too short.
    TooShort {
        /// What is short.
        what: &'static str,
        /// The value found.
        found: f64,
        /// The least accepted.
        min: f64,
    },
    /// The motor did not move although torque was applied.
    Stalled {
        /// Range of θa covered (rad).
        range_rad: f64,
        /// Largest measured torque (N·m).
        max_torque_nm: f64,
    },
    /// The free sweep is stiffer than a free finger can be: something was touched.
    ObjectTouched {
        /// θa where the stiffness jumped (rad).
        theta_a_rad: f64,
        /// The local stiffness found (N·m/rad).
        stiffness_nm_per_rad: f64,
        /// The largest free-motion stiffness accepted (N·m/rad).
        limit_nm_per_rad: f64,
    },
    /// The residual is too large for the model.
    TooNoisy {
        /// Residual RMS (N·m).
        rms_nm: f64,
        /// Largest accepted (N·m).
        limit_nm: f64,
    },
    /// A value in the trace is not finite or time does not increase.
    BadTrace(String),
    /// The fit did not converge or its normal matrix is singular.
    NoFit(String),
    /// The nominal finger or the identified one is not a valid finger.
    Finger(String),
}

impl fmt::Display for CalibError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CalibError::TooShort { what, found, min } => {
                write!(
                    f,
                    "sweep too short: {what} = {found:.4}, at least {min} needed"
                )
            }
            CalibError::Stalled {
                range_rad,
                max_torque_nm,
            } => write!(
                f,
                "stalled motor: θa moved {range_rad:.4} rad (at least 0.1 rad needed) with up \
                 to {max_torque_nm:.3} N·m"
            ),
            CalibError::ObjectTouched {
                theta_a_rad,
                stiffness_nm_per_rad,
                limit_nm_per_rad,
            } => write!(
                f,
                "object touched: stiffness {stiffness_nm_per_rad:.3} N·m/rad at θa = \
                 {theta_a_rad:.4} rad, above the {limit_nm_per_rad:.3} N·m/rad a free finger can \
                 have"
            ),
            CalibError::TooNoisy { rms_nm, limit_nm } => write!(
                f,
                "too noisy: residual RMS {rms_nm:.4} N·m above the accepted {limit_nm:.4} N·m"
            ),
            CalibError::BadTrace(m) => write!(f, "bad trace: {m}"),
            CalibError::NoFit(m) => write!(f, "no fit: {m}"),
            CalibError::Finger(m) => write!(f, "finger: {m}"),
        }
    }
}

impl std::error::Error for CalibError {}

/// One identified parameter.
#[derive(Clone, Debug, PartialEq)]
pub struct Param {
    /// Name (as in the JSON output).
    pub name: &'static str,
    /// Identified value (in `unit`).
    pub value: f64,
    /// 1σ (in `unit`); `None` when it is not identified (kept at the nominal).
    pub sigma: Option<f64>,
    /// The nominal file's value, when the file has one.
    pub nominal: Option<f64>,
    /// Unit.
    pub unit: &'static str,
    /// Where it goes in the finger file (`None`: reported only).
    pub file_key: Option<&'static str>,
}

/// The result of a calibration.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// Every parameter, identified or kept.
    pub params: Vec<Param>,
    /// Residual RMS of the torque fit (N·m).
    pub residual_rms_nm: f64,
    /// Factor the σ were inflated by for the residual's correlation (≥ 1).
    pub correlation_factor: f64,
    /// Samples used in the fit.
    pub samples: usize,
    /// What this recording could not separate, for people.
    pub notes: Vec<String>,
    /// The calibrated finger file.
    pub file: FingerFile,
}

impl Calibration {
    /// The parameter called `name`.
    pub fn get(&self, name: &str) -> Option<&Param> {
        self.params.iter().find(|p| p.name == name)
    }

    /// JSON form.
    pub fn to_json(&self) -> Value {
        json!({
            "params": self.params.iter().map(|p| json!({
                "name": p.name, "value": p.value, "sigma": p.sigma, "nominal": p.nominal,
                "unit": p.unit, "file_key": p.file_key,
            })).collect::<Vec<_>>(),
            "residual_rms_nm": self.residual_rms_nm,
            "correlation_factor": self.correlation_factor,
            "samples": self.samples,
            "notes": self.notes,
        })
    }
}

impl fmt::Display for Calibration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{:<18} {:>14} {:>12} {:>14}  {:<10} file key",
            "parameter", "value", "σ", "nominal", "unit"
        )?;
        for p in &self.params {
            let s = p
                .sigma
                .map_or("not identified".to_string(), |s| format!("{s:.4e}"));
            let n = p.nominal.map_or("-".to_string(), |n| format!("{n:.6}"));
            writeln!(
                f,
                "{:<18} {:>14.6} {:>12} {:>14}  {:<10} {}",
                p.name,
                p.value,
                s,
                n,
                p.unit,
                p.file_key.unwrap_or("(reported only)")
            )?;
        }
        writeln!(
            f,
            "residual RMS {:.5} N·m over {} samples (σ × {:.2} for the residual's correlation)",
            self.residual_rms_nm, self.samples, self.correlation_factor
        )?;
        for n in &self.notes {
            writeln!(f, "note: {n}")?;
        }
        Ok(())
    }
}

/// A recording prepared for the fit.
struct Prepared {
    /// θa − the nominal rest (rad), the encoder's angle.
    dth: Vec<f64>,
    /// Measured torque (N·m).
    t: Vec<f64>,
    /// θ̇a (rad/s).
    v: Vec<f64>,
    /// θ̈a (rad/s²).
    a: Vec<f64>,
    /// Indices used in the fit.
    used: Vec<usize>,
    /// Breakaway samples: (index, direction +1 closing / −1 opening).
    breaks: Vec<(usize, f64)>,
    /// The post of a touch recording.
    post: Option<Post>,
}

/// σ of the prior on θ0,2 (rad): 5°, a drawing's tolerance on a spring's rest angle.
pub const THETA02_PRIOR_RAD: f64 = 5.0 * core::f64::consts::PI / 180.0;
/// Half-width of the Savitzky–Golay window (samples).
const SG_HALF: usize = 25;
/// Least number of moving samples per direction.
const MIN_MOVING: usize = 200;
/// Speed under which the finger counts as stopped (rad/s at the crank).
const V_STOP: f64 = 0.01;

fn prepare(
    rows: &[TraceRow],
    rest_nominal: f64,
    post: Option<Post>,
) -> Result<Prepared, CalibError> {
    if rows.len() < 4 * SG_HALF {
        return Err(CalibError::TooShort {
            what: "rows",
            found: rows.len() as f64,
            min: (4 * SG_HALF) as f64,
        });
    }
    for (i, r) in rows.iter().enumerate() {
        if !(r.t_s.is_finite() && r.theta_a_rad.is_finite() && r.torque_nm.is_finite()) {
            return Err(CalibError::BadTrace(format!(
                "row {i}: a value is not finite"
            )));
        }
        if i > 0 && r.t_s <= rows[i - 1].t_s {
            return Err(CalibError::BadTrace(format!(
                "row {i}: t_s = {} does not increase",
                r.t_s
            )));
        }
    }
    let n = rows.len();
    let duration = rows[n - 1].t_s - rows[0].t_s;
    if duration < 2.0 {
        return Err(CalibError::TooShort {
            what: "duration (s)",
            found: duration,
            min: 2.0,
        });
    }
    let dt = duration / (n - 1) as f64;
    let th: Vec<f64> = rows.iter().map(|r| r.theta_a_rad - rest_nominal).collect();
    let t: Vec<f64> = rows.iter().map(|r| r.torque_nm).collect();
    let (lo, hi) = th
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
            (l.min(*x), h.max(*x))
        });
    let tmax = t.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if hi - lo < 0.1 {
        return Err(CalibError::Stalled {
            range_rad: hi - lo,
            max_torque_nm: tmax,
        });
    }
    // Savitzky–Golay quadratic: first and second derivative.
    let m = SG_HALF as i64;
    let s2: f64 = (-m..=m).map(|k| (k * k) as f64).sum();
    let nw = (2 * m + 1) as f64;
    let c2: f64 = (-m..=m).map(|k| ((k * k) as f64 - s2 / nw).powi(2)).sum();
    let mut v = vec![0.0; n];
    let mut a = vec![0.0; n];
    for j in SG_HALF..n - SG_HALF {
        let (mut s1, mut q) = (0.0, 0.0);
        for k in -m..=m {
            let y = th[(j as i64 + k) as usize];
            s1 += k as f64 * y;
            q += ((k * k) as f64 - s2 / nw) * y;
        }
        v[j] = s1 / (s2 * dt);
        a[j] = 2.0 * q / (c2 * dt * dt);
    }
    // Moving samples: a steady direction over the whole window and away from the ends.
    let mut used = vec![];
    let mut breaks = vec![];
    let mut stopped_for = 0usize;
    for j in SG_HALF..n - SG_HALF {
        let moving = v[j].abs() > V_STOP;
        if !moving {
            stopped_for += 1;
            continue;
        }
        if stopped_for >= SG_HALF {
            breaks.push((j, v[j].signum()));
        }
        stopped_for = 0;
        let lo = j.saturating_sub(SG_HALF);
        let hi = (j + SG_HALF).min(n - SG_HALF - 1);
        let steady = (lo..=hi).all(|i| v[i] * v[j] > 0.0 && v[i].abs() > 0.3 * V_STOP);
        if steady && th[j] > 0.02 {
            used.push(j);
        }
    }
    let closing = used.iter().filter(|&&j| v[j] > 0.0).count();
    let opening = used.len() - closing;
    for (what, k) in [
        ("moving samples closing", closing),
        ("moving samples opening", opening),
    ] {
        if k < MIN_MOVING {
            return Err(CalibError::TooShort {
                what,
                found: k as f64,
                min: MIN_MOVING as f64,
            });
        }
    }
    Ok(Prepared {
        dth: th,
        t,
        v,
        a,
        used,
        breaks,
        post,
    })
}

/// Parameters of the static map.
#[derive(Clone, Copy, Debug)]
struct Statics {
    k1: f64,
    k2: f64,
    theta01: f64,
    theta02: f64,
}

/// Spring torque L at encoder angle Δθa (relative to the encoder zero, backlash removed) for
/// the finger with these statics, free or held by the post.
struct StaticMap {
    model: Model<f64>,
    rest: f64,
    phi2: f64,
}

impl StaticMap {
    fn new(base: &Finger, s: Statics) -> Result<StaticMap, String> {
        let finger = Finger {
            k1: s.k1,
            k2: s.k2,
            theta01: s.theta01,
            theta02: s.theta02,
            ..*base
        };
        let model = Model::<f64>::new(&finger).map_err(|e| e.to_string())?;
        let rest = model
            .theta_a(s.theta01, s.theta02)
            .map_err(|e| e.to_string())?;
        Ok(StaticMap {
            model,
            rest,
            phi2: base.phi2,
        })
    }

    fn torque(&self, dth: f64, post: Option<Post>) -> Result<f64, String> {
        let ta = self.rest + dth;
        let free = self
            .model
            .free_from_theta_a(ta)
            .map_err(|e| e.to_string())?;
        let Some(p) = post else {
            return Ok(free.ta);
        };
        if free.theta1 <= p.theta1_rad {
            return Ok(free.ta);
        }
        // θ1 held at the post: solve θa(θ1p, θ2) = ta for θ2 (∂θa/∂θ2 = x2).
        let f = &self.model.finger;
        let mut t2 = free.theta2;
        for _ in 0..40 {
            let c = self.model.closure(t2).map_err(|e| e.to_string())?;
            let th = p.theta1_rad + t2 - self.phi2 - c.gamma;
            let step = (th - ta) / c.x2;
            t2 -= step;
            if step.abs() < 1e-13 {
                break;
            }
        }
        let c = self.model.closure(t2).map_err(|e| e.to_string())?;
        Ok(f.k2 * (t2 - f.theta02) / c.x2)
    }
}

/// Encoder angle Δθa (rad, backlash included) at which the free finger with these statics
/// first meets the distal post, or `None` if it does not below 1.5 N·m.
fn tip_contact_predicted(map: &StaticMap, post: DistalPost, half_backlash: f64) -> Option<f64> {
    let f = &map.model.finger;
    let gap = |ta: f64| -> Option<(f64, f64, f64)> {
        let c = map.model.free_from_torque(ta).ok()?;
        let (o2x, o2y) = (f.l1 * c.theta1.cos(), f.l1 * c.theta1.sin());
        let ang = c.theta1 + c.theta2;
        let (ux, uy) = (ang.cos(), ang.sin());
        let (dx, dy) = (post.x_m - o2x, post.y_m - o2y);
        // Left normal distance (positive while the post is ahead) and the place along the
        // phalanx.
        Some((ux * dy - uy * dx, ux * dx + uy * dy, c.theta_a))
    };
    let mut lo = 0.0;
    let (g0, _, _) = gap(lo)?;
    if g0 <= 0.0 {
        return None;
    }
    let mut hi = None;
    let mut t = 0.0;
    while t < 1.5 {
        t += 0.01;
        let (g, k, _) = gap(t)?;
        if g <= 0.0 {
            if !(0.0..=f.l2).contains(&k) {
                return None;
            }
            hi = Some(t);
            break;
        }
        lo = t;
    }
    let mut hi = hi?;
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if gap(mid)?.0 > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let (_, _, ta) = gap(0.5 * (lo + hi))?;
    Some(ta - map.rest + half_backlash)
}

/// Encoder angle Δθa (rad) at which the closing finger met the distal post, and its σ: where
/// the torque first exceeds the free-motion model (the fit's statics and drive terms) by more
/// than the noise, extrapolated back to zero excess along the stiff contact.
fn tip_contact_measured(
    rec: &Prepared,
    map: &StaticMap,
    p: &[f64; 9],
    half_backlash: f64,
    noise: f64,
    dt: f64,
) -> Result<(f64, f64), CalibError> {
    let closing: Vec<usize> = rec
        .used
        .iter()
        .copied()
        .filter(|&j| rec.v[j] > 0.0)
        .collect();
    let excess: Vec<f64> = closing
        .iter()
        .map(|&j| {
            let l = map
                .torque(rec.dth[j] - half_backlash, None)
                .unwrap_or(f64::NAN);
            rec.t[j] - (l + p[5] + p[6] * rec.v[j] + p[7] * rec.a[j] + p[8])
        })
        .collect();
    let thr = (6.0 * noise).max(0.02);
    let q = (1..excess.len())
        .find(|&i| excess[i] > thr && excess.get(i + 1).is_none_or(|e| *e > thr))
        .ok_or(CalibError::TooShort {
            what: "excess torque over free motion on the tip touch (N·m)",
            found: excess.iter().copied().fold(0.0, f64::max),
            min: thr,
        })?;
    // Line through the excess against θa from the detection on (contact stiffness), back to
    // zero excess.
    let pts: Vec<(f64, f64)> = (q.saturating_sub(3)..excess.len())
        .take(30)
        .filter(|&i| excess[i] > 0.5 * thr && excess[i] < 0.3)
        .map(|i| (rec.dth[closing[i]], excess[i]))
        .collect();
    let fallback = rec.dth[closing[q - 1]];
    let bracket = (rec.dth[closing[q]] - fallback).abs();
    let smear = 0.5 * rec.v[closing[q]].abs() * SG_HALF as f64 * dt;
    let mut at = fallback;
    if pts.len() >= 3 {
        let n = pts.len() as f64;
        let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
        let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
        let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        if sxx > 0.0 && sxy > 0.0 {
            let x0 = mx - my * sxx / sxy;
            if (x0 - fallback).abs() < 0.05 {
                at = x0;
            }
        }
    }
    Ok((at, (bracket * bracket + smear * smear).sqrt().max(1e-4)))
}

/// A fit of the parameter vector [K1, K2, θ0,1, θ0,2, ρ, F_c, b, J, T_off].
struct Fit {
    p: [f64; 9],
    free: [bool; 9],
    cov: [[f64; 9]; 9],
    rms: f64,
    corr_factor: f64,
    samples: usize,
}

/// A prior on one parameter: (index, value, weight = residual σ / prior σ), one more row of
/// the least squares.
type Prior = Option<(usize, f64, f64)>;

fn residuals(
    recs: &[Prepared],
    base: &Finger,
    p: &[f64; 9],
    half_backlash: f64,
    prior: Prior,
) -> Result<Vec<f64>, String> {
    let map = StaticMap::new(
        base,
        Statics {
            k1: p[0],
            k2: p[1],
            theta01: p[2],
            theta02: p[3],
        },
    )?;
    let mut r = vec![];
    for rec in recs {
        for &j in &rec.used {
            let l = map.torque(rec.dth[j] - half_backlash, rec.post)?;
            let s = rec.v[j].signum();
            let scale = if s > 0.0 { 1.0 } else { p[4] };
            let model = l * scale + p[5] * s + p[6] * rec.v[j] + p[7] * rec.a[j] + p[8];
            r.push(rec.t[j] - model);
        }
    }
    if let Some((i, v, w)) = prior {
        r.push(w * (v - p[i]));
    }
    Ok(r)
}

fn fit(
    recs: &[Prepared],
    base: &Finger,
    p0: [f64; 9],
    free: [bool; 9],
    half_backlash: f64,
    prior: Prior,
) -> Result<Fit, CalibError> {
    let idx: Vec<usize> = (0..9).filter(|&i| free[i]).collect();
    let mut p = p0;
    let steps = [
        1e-5 * p0[0].abs().max(1e-3),
        1e-5 * p0[1].abs().max(1e-3),
        1e-5,
        1e-5,
    ];
    let mut r = residuals(recs, base, &p, half_backlash, prior).map_err(CalibError::NoFit)?;
    let mut jac: Vec<Vec<f64>> = vec![];
    for _iter in 0..30 {
        // Jacobian of the model (= −∂r/∂p).
        jac.clear();
        for &i in &idx {
            if i < 4 {
                let mut pp = p;
                let mut pm = p;
                pp[i] += steps[i];
                pm[i] -= steps[i];
                let rp =
                    residuals(recs, base, &pp, half_backlash, prior).map_err(CalibError::NoFit)?;
                let rm =
                    residuals(recs, base, &pm, half_backlash, prior).map_err(CalibError::NoFit)?;
                jac.push(
                    rp.iter()
                        .zip(&rm)
                        .map(|(a, b)| (b - a) / (2.0 * steps[i]))
                        .collect(),
                );
            } else {
                let mut pp = p;
                pp[i] += 1.0;
                let rp =
                    residuals(recs, base, &pp, half_backlash, prior).map_err(CalibError::NoFit)?;
                jac.push(r.iter().zip(&rp).map(|(a, b)| a - b).collect());
            }
        }
        let k = idx.len();
        let mut jtj = vec![vec![0.0; k]; k];
        let mut jtr = vec![0.0; k];
        for a in 0..k {
            for b in a..k {
                let s: f64 = jac[a].iter().zip(&jac[b]).map(|(x, y)| x * y).sum();
                jtj[a][b] = s;
                jtj[b][a] = s;
            }
            jtr[a] = jac[a].iter().zip(&r).map(|(x, y)| x * y).sum();
        }
        let inv = crate::linalg::invert(jtj)
            .ok_or_else(|| CalibError::NoFit("singular normal matrix".into()))?;
        let delta: Vec<f64> = (0..k)
            .map(|a| (0..k).map(|b| inv[a][b] * jtr[b]).sum())
            .collect();
        let cost0: f64 = r.iter().map(|x| x * x).sum();
        // Step halving keeps the cost from rising.
        let mut lambda = 1.0;
        let mut accepted = false;
        for _ in 0..12 {
            let mut pn = p;
            for (a, &i) in idx.iter().enumerate() {
                pn[i] += lambda * delta[a];
            }
            if let Ok(rn) = residuals(recs, base, &pn, half_backlash, prior) {
                let cost: f64 = rn.iter().map(|x| x * x).sum();
                if cost <= cost0 {
                    let rel = (cost0 - cost) / cost0.max(1e-300);
                    p = pn;
                    r = rn;
                    accepted = true;
                    if rel < 1e-12 {
                        return finish(p, free, &idx, &jac, &r);
                    }
                    break;
                }
            }
            lambda *= 0.5;
        }
        if !accepted {
            return finish(p, free, &idx, &jac, &r);
        }
    }
    finish(p, free, &idx, &jac, &r)
}

fn finish(
    p: [f64; 9],
    free: [bool; 9],
    idx: &[usize],
    jac: &[Vec<f64>],
    r: &[f64],
) -> Result<Fit, CalibError> {
    let n = r.len();
    let k = idx.len();
    let rss: f64 = r.iter().map(|x| x * x).sum();
    let s2 = rss / (n.saturating_sub(k)).max(1) as f64;
    // Lag-1 autocorrelation of the residual: n_eff = n (1 − ρ1)/(1 + ρ1).
    let r1 = if rss > 0.0 {
        r.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / rss
    } else {
        0.0
    };
    let r1 = r1.clamp(0.0, 0.999);
    let corr_factor = ((1.0 + r1) / (1.0 - r1)).sqrt();
    let mut jtj = vec![vec![0.0; k]; k];
    for a in 0..k {
        for b in 0..k {
            jtj[a][b] = jac[a].iter().zip(&jac[b]).map(|(x, y)| x * y).sum();
        }
    }
    let inv = crate::linalg::invert(jtj)
        .ok_or_else(|| CalibError::NoFit("singular normal matrix".into()))?;
    let mut cov = [[0.0; 9]; 9];
    for (a, &i) in idx.iter().enumerate() {
        for (b, &j) in idx.iter().enumerate() {
            cov[i][j] = inv[a][b] * s2 * corr_factor * corr_factor;
        }
    }
    Ok(Fit {
        p,
        free,
        cov,
        rms: (rss / n.max(1) as f64).sqrt(),
        corr_factor,
        samples: n,
    })
}

/// The recording's breakaway torques from standstill: stiction at the crank, one value per
/// breakaway, with the statics and drive terms of the fit removed.
fn stiction(recs: &[Prepared], base: &Finger, p: &[f64; 9], half_backlash: f64) -> Vec<f64> {
    let Ok(map) = StaticMap::new(
        base,
        Statics {
            k1: p[0],
            k2: p[1],
            theta01: p[2],
            theta02: p[3],
        },
    ) else {
        return vec![];
    };
    let mut out = vec![];
    for rec in recs {
        for &(j, dir) in &rec.breaks {
            // The torque just before the first motion, averaged over a few samples; the
            // breakaway is where the smoothed speed first crosses the stop threshold, about
            // half a window after the shaft let go.
            let end = j.saturating_sub(SG_HALF / 2);
            let start = end.saturating_sub(10);
            if end <= start {
                continue;
            }
            let tm = rec.t[start..end].iter().sum::<f64>() / (end - start) as f64;
            let th = rec.dth[end];
            let l = if th > half_backlash {
                map.torque(th - half_backlash, rec.post).unwrap_or(0.0)
            } else {
                0.0
            };
            let s = if dir > 0.0 {
                tm - l - p[8]
            } else {
                p[4] * l - tm + p[8]
            };
            out.push(s);
        }
    }
    out
}

/// The largest stiffness a free finger of the nominal file can show with springs up to 1.5×
/// and the closing direction (N·m/rad), over the sweep's range.
fn free_stiffness_limit(nominal: &Finger, max_dth: f64) -> f64 {
    let stiff = Finger {
        k1: nominal.k1 * 1.5,
        k2: nominal.k2 * 1.5,
        ..*nominal
    };
    let Ok(m) = Model::<f64>::new(&stiff) else {
        return f64::INFINITY;
    };
    let Ok(rest) = m.theta_a(stiff.theta01, stiff.theta02) else {
        return f64::INFINITY;
    };
    let mut kmax: f64 = 0.0;
    for i in 0..=50 {
        let th = rest + max_dth * f64::from(i) / 50.0;
        if let Ok(c) = m.free_from_theta_a(th) {
            if let Ok(k) = m.kc_free(c.theta2, c.ta) {
                kmax = kmax.max(k);
            }
        }
    }
    2.0 * kmax
}

/// Local stiffness check of a free sweep's closing branch (object touched): the measured
/// torque with the fitted friction, viscous, inertia and offset terms removed is the spring
/// torque, whose slope over windows of 0.1 rad of θa cannot exceed a free finger's.
fn check_free(rec: &Prepared, nominal: &Finger, p: &[f64; 9]) -> Result<(), CalibError> {
    let closing: Vec<usize> = rec
        .used
        .iter()
        .copied()
        .filter(|&j| rec.v[j] > 0.0)
        .collect();
    let max_dth = closing.iter().map(|&j| rec.dth[j]).fold(0.0, f64::max);
    let limit = free_stiffness_limit(nominal, max_dth + 0.1);
    let spring = |j: usize| rec.t[j] - p[5] - p[6] * rec.v[j] - p[7] * rec.a[j] - p[8];
    let mut sorted = closing;
    sorted.sort_by(|&x, &y| rec.dth[x].total_cmp(&rec.dth[y]));
    let mut i0 = 0;
    while i0 < sorted.len() {
        let th0 = rec.dth[sorted[i0]];
        let mut i1 = i0;
        while i1 + 1 < sorted.len() && rec.dth[sorted[i1 + 1]] < th0 + 0.1 {
            i1 += 1;
        }
        if i1 - i0 >= 20 && rec.dth[sorted[i1]] - th0 > 0.05 {
            let pts: Vec<(f64, f64)> = sorted[i0..=i1]
                .iter()
                .map(|&j| (rec.dth[j], spring(j)))
                .collect();
            let n = pts.len() as f64;
            let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
            let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
            let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
            let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
            if sxx > 0.0 {
                let k = sxy / sxx;
                if k > limit {
                    return Err(CalibError::ObjectTouched {
                        theta_a_rad: mx,
                        stiffness_nm_per_rad: k,
                        limit_nm_per_rad: limit,
                    });
                }
            }
        }
        i0 = i1 + 1;
    }
    Ok(())
}

/// Identifies the finger from a free sweep and, optionally, a touch against a post.
///
/// `nominal` is the file the sweep was recorded with (its rest angle is the encoder zero of
/// the trace's θa, its constants converted the current to torque).
pub fn identify(
    sweep: &[TraceRow],
    touch: Option<(&[TraceRow], Post)>,
    nominal: &FingerFile,
) -> Result<Calibration, CalibError> {
    identify_with(sweep, touch, None, nominal)
}

/// [`identify`] with a third recording, the free finger closing onto a [`DistalPost`]: the
/// angle at which it meets the post fixes θ0,2 (with K1, K2 and θ0,1 from the other two),
/// which neither the free sweep nor the proximal post can.
pub fn identify_with(
    sweep: &[TraceRow],
    touch: Option<(&[TraceRow], Post)>,
    tip: Option<(&[TraceRow], DistalPost)>,
    nominal: &FingerFile,
) -> Result<Calibration, CalibError> {
    let base = nominal.finger;
    let rest_nominal = statics_map(&base, &[base.k1, base.k2, base.theta01, base.theta02])?.rest;
    let recs = prepare_recordings(sweep, touch, &base, rest_nominal)?;
    let half_backlash = 0.5 * nominal.drive.backlash_rad;
    let mut f = fit_statics(&recs, &base, nominal, half_backlash)?;
    refuse_bad_fit(&recs, &base, &f)?;
    let with_touch = recs.len() > 1;
    let st = stiction(&recs, &base, &f.p, half_backlash);
    let mut theta02_sigma = None;
    if let Some((rows, post)) = tip {
        if !with_touch {
            return Err(CalibError::BadTrace(
                "the tip touch needs the proximal touch too (K1, K2 and θ0,1 come from it)".into(),
            ));
        }
        let (theta02, sigma) =
            theta02_from_tip(rows, post, &base, &f, rest_nominal, half_backlash)?;
        f.p[3] = theta02;
        theta02_sigma = Some(sigma);
    }
    let sig = |i: usize| {
        if i == 3 && theta02_sigma.is_some() {
            return theta02_sigma;
        }
        f.free[i].then(|| f.cov[i][i].max(0.0).sqrt())
    };
    let notes = identifiability_notes(&f, with_touch, &sig);
    let stiction_param = Param {
        name: "stiction",
        value: f64::NAN,
        sigma: None,
        nominal: None,
        unit: "N·m",
        file_key: None,
    };
    let stiction_param = match stiction_stats(&st, &f) {
        Some((value, sigma)) => Param {
            value,
            sigma: Some(sigma),
            ..stiction_param
        },
        None => stiction_param,
    };
    let file = calibrated_file(nominal, &f.p)?;
    let params = calibrated_params(&base, nominal, &f.p, &sig, stiction_param);
    Ok(Calibration {
        params,
        residual_rms_nm: f.rms,
        correlation_factor: f.corr_factor,
        samples: f.samples,
        notes,
        file,
    })
}

/// The static map of `base` with the statics `p[0..4]` = (K1, K2, θ0,1, θ0,2).
fn statics_map(base: &Finger, p: &[f64]) -> Result<StaticMap, CalibError> {
    StaticMap::new(
        base,
        Statics {
            k1: p[0],
            k2: p[1],
            theta01: p[2],
            theta02: p[3],
        },
    )
    .map_err(CalibError::Finger)
}

/// The free sweep and, when given, the proximal-post touch, prepared and thinned to at most
/// 4000 samples each (the residual's correlation is accounted for in σ either way).
fn prepare_recordings(
    sweep: &[TraceRow],
    touch: Option<(&[TraceRow], Post)>,
    base: &Finger,
    rest_nominal: f64,
) -> Result<Vec<Prepared>, CalibError> {
    let mut recs = vec![prepare(sweep, rest_nominal, None)?];
    if let Some((rows, post)) = touch {
        if !(post.theta1_rad.is_finite()
            && post.theta1_rad > base.theta01 + 0.1
            && post.theta1_rad < base.theta01 + 1.5)
        {
            return Err(CalibError::BadTrace(format!(
                "post θ1 = {} rad is outside (θ0,1 + 0.1, θ0,1 + 1.5) = ({:.4}, {:.4}) rad",
                post.theta1_rad,
                base.theta01 + 0.1,
                base.theta01 + 1.5
            )));
        }
        recs.push(prepare(rows, rest_nominal, Some(post))?);
    }
    for rec in &mut recs {
        let stride = rec.used.len().div_ceil(4000).max(1);
        rec.used = rec.used.iter().copied().step_by(stride).collect();
    }
    Ok(recs)
}

/// The least-squares fit of the statics and the drive: the free sweep first (θ0,1 does not
/// enter it); with the touch, from there over a few starting θ0,1 (the contact with the post
/// makes the cost non-convex in θ0,1).
fn fit_statics(
    recs: &[Prepared],
    base: &Finger,
    nominal: &FingerFile,
    half_backlash: f64,
) -> Result<Fit, CalibError> {
    let p0 = [
        base.k1,
        base.k2,
        base.theta01,
        base.theta02,
        0.5,
        0.0,
        0.0,
        nominal.drive.inertia_kgm2,
        0.0,
    ];
    let mut free_mask = [true; 9];
    free_mask[2] = false;
    // θ0,2 enters the torque only through the slow change of x2 (and cancels to first order
    // after contact with the post too): the fit takes the file's value as a prior of σ
    // THETA02_PRIOR_RAD, the tolerance of a rest angle on a drawing, so that a sweep that
    // cannot see it does not move it far.
    let pre = fit(&recs[..1], base, p0, free_mask, half_backlash, None)?;
    let prior: Prior = Some((
        3,
        base.theta02,
        pre.rms * pre.corr_factor / THETA02_PRIOR_RAD,
    ));
    let f = fit(&recs[..1], base, pre.p, free_mask, half_backlash, prior)?;
    if recs.len() == 1 {
        return Ok(f);
    }
    free_mask[2] = true;
    let mut best: Option<Fit> = None;
    for d_deg in [0.0, -2.5, 2.5, -5.0, 5.0] {
        let mut start = f.p;
        start[2] = base.theta01 + f64::to_radians(d_deg);
        if let Ok(g) = fit(recs, base, start, free_mask, half_backlash, prior) {
            if best.as_ref().is_none_or(|b| g.rms < b.rms) {
                best = Some(g);
            }
        }
    }
    best.ok_or_else(|| CalibError::NoFit("no start converged with the touch".into()))
}

/// Refusals that need the fit: a free sweep the identified finger could not have made, and a
/// residual above 5 % of the torque range (at least 0.01 N·m).
fn refuse_bad_fit(recs: &[Prepared], base: &Finger, f: &Fit) -> Result<(), CalibError> {
    let range: f64 = recs
        .iter()
        .flat_map(|r| r.used.iter().map(|&j| r.t[j]))
        .fold(0.0, |m, x| m.max(x.abs()));
    let limit = (0.05 * range).max(0.01);
    check_free(&recs[0], base, &f.p)?;
    if f.rms > limit {
        return Err(CalibError::TooNoisy {
            rms_nm: f.rms,
            limit_nm: limit,
        });
    }
    Ok(())
}

/// θ0,2 and its σ from the tip touch: Newton on the angle at which the model finger meets the
/// distal post; σ from the measured angle's and the other statics' uncertainty.
fn theta02_from_tip(
    rows: &[TraceRow],
    post: DistalPost,
    base: &Finger,
    f: &Fit,
    rest_nominal: f64,
    half_backlash: f64,
) -> Result<(f64, f64), CalibError> {
    let rec = prepare(rows, rest_nominal, None)?;
    let dt = (rows[rows.len() - 1].t_s - rows[0].t_s) / (rows.len() - 1) as f64;
    let map = statics_map(base, &f.p)?;
    let (meas, meas_sigma) =
        tip_contact_measured(&rec, &map, &f.p, half_backlash, f.rms * f.corr_factor, dt)?;
    let pred = |p: &[f64; 9]| -> Result<f64, CalibError> {
        tip_contact_predicted(&statics_map(base, p)?, post, half_backlash).ok_or_else(|| {
            CalibError::NoFit("the model finger does not meet the distal post".into())
        })
    };
    let h = 1e-4;
    let slope = |p: &[f64; 9], i: usize, step: f64| -> Result<f64, CalibError> {
        let (mut a, mut b) = (*p, *p);
        a[i] += step;
        b[i] -= step;
        Ok((pred(&a)? - pred(&b)?) / (2.0 * step))
    };
    let mut p = f.p;
    for _ in 0..20 {
        let d = slope(&p, 3, h)?;
        if d.abs() < 1e-6 {
            return Err(CalibError::NoFit(
                "the distal post does not see θ0,2".into(),
            ));
        }
        let step = (meas - pred(&p)?) / d;
        p[3] += step.clamp(-0.1, 0.1);
        if step.abs() < 1e-9 {
            break;
        }
    }
    let d = slope(&p, 3, h)?;
    let mut var = (meas_sigma / d).powi(2);
    for i in 0..3 {
        let s = f.cov[i][i].max(0.0).sqrt();
        if s > 0.0 {
            var += (slope(&p, i, 0.5 * s)? * s / d).powi(2);
        }
    }
    Ok((p[3], var.sqrt()))
}

/// What the recordings could not separate, in words for the report.
fn identifiability_notes(
    f: &Fit,
    with_touch: bool,
    sig: &dyn Fn(usize) -> Option<f64>,
) -> Vec<String> {
    let mut notes = vec![];
    if !with_touch {
        notes.push(
            "θ0,1 is not identifiable from a free sweep (θ1 is not measured): kept at the \
             nominal; add --touch with a post to identify it"
                .to_string(),
        );
    }
    let rel = |i: usize| sig(i).map_or(f64::INFINITY, |s| s / f.p[i].abs().max(1e-12));
    if rel(0) > 0.05 || rel(1) > 0.05 {
        notes.push(format!(
            "K1 and K2 are poorly separated by this recording (σ/K: {:.1} %, {:.1} %; \
             correlation {:.3}): only their series compliance is well known; add --touch",
            100.0 * rel(0),
            100.0 * rel(1),
            f.cov[0][1] / (f.cov[0][0] * f.cov[1][1]).sqrt().max(1e-300)
        ));
    }
    notes.push(
        "the torque scale (kt·η·current gain) and the backlash are not identifiable: springs \
         and friction are in the units of the measured torque, the backlash is the file's"
            .to_string(),
    );
    notes
}

/// The mean breakaway torque and its σ: the spread of the breakaways, or the residual over
/// the ten samples averaged and the torque ramp over the smoothing window, whichever is
/// larger. `None` when the recordings show no breakaway.
fn stiction_stats(st: &[f64], f: &Fit) -> Option<(f64, f64)> {
    if st.is_empty() {
        return None;
    }
    let m = st.iter().sum::<f64>() / st.len() as f64;
    let var = if st.len() > 1 {
        st.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (st.len() - 1) as f64
    } else {
        0.0
    };
    let floor = f.rms * f.corr_factor / 10f64.sqrt();
    Some((m, (var / st.len() as f64).sqrt().max(floor)))
}

/// The nominal file with the identified statics, inertia and current-sense zero, checked as
/// every consumer checks a finger file.
fn calibrated_file(nominal: &FingerFile, p: &[f64; 9]) -> Result<FingerFile, CalibError> {
    let mut file = nominal.clone();
    file.name = format!("{} (calibrated)", nominal.name);
    file.finger.k1 = p[0];
    file.finger.k2 = p[1];
    file.finger.theta01 = p[2];
    file.finger.theta02 = p[3];
    // The sweeps do not see the stops: they keep their offsets from the rest angles (a rest
    // angle identified below a nominal stop would otherwise be refused).
    file.stops.theta1_min_rad += p[2] - nominal.finger.theta01;
    file.stops.theta2_min_rad += p[3] - nominal.finger.theta02;
    file.drive.inertia_kgm2 = p[7].max(0.0);
    let off_a = nominal.current_from_torque(p[8]);
    let zero =
        f64::from(nominal.current_sense.zero_count) + off_a / nominal.current_sense.amps_per_count;
    let max_code = (1u32 << nominal.current_sense.adc_bits) - 1;
    file.current_sense.zero_count = zero.round().clamp(0.0, f64::from(max_code)) as u32;
    let checked = FingerFile::from_toml_str(&file.to_toml_string())
        .map_err(|e| CalibError::Finger(format!("the calibrated finger is refused: {e}")))?;
    crate::replay::controller_config(&checked, grasp::DriveConfig::DEFAULT.dt_s)
        .map_err(|e| CalibError::Finger(format!("the calibrated finger is refused: {e}")))?;
    Ok(checked)
}

/// The identified parameters in report order, each with its σ, nominal and file key.
fn calibrated_params(
    base: &Finger,
    nominal: &FingerFile,
    p: &[f64; 9],
    sig: &dyn Fn(usize) -> Option<f64>,
    stiction: Param,
) -> Vec<Param> {
    let nm = |name, i: usize, nominal, unit, file_key| Param {
        name,
        value: p[i],
        sigma: sig(i),
        nominal,
        unit,
        file_key,
    };
    vec![
        nm(
            "k1",
            0,
            Some(base.k1),
            "N·m/rad",
            Some("springs.k1_nm_per_rad"),
        ),
        nm(
            "k2",
            1,
            Some(base.k2),
            "N·m/rad",
            Some("springs.k2_nm_per_rad"),
        ),
        nm(
            "theta01",
            2,
            Some(base.theta01),
            "rad",
            Some("springs.theta01_rad"),
        ),
        nm(
            "theta02",
            3,
            Some(base.theta02),
            "rad",
            Some("springs.theta02_rad"),
        ),
        nm("backdrive_ratio", 4, None, "-", None),
        nm("coulomb", 5, None, "N·m", None),
        stiction,
        nm("viscous", 6, None, "N·m·s/rad", None),
        nm(
            "inertia",
            7,
            Some(nominal.drive.inertia_kgm2),
            "kg·m²",
            Some("drive.inertia_kgm2"),
        ),
        nm(
            "torque_offset",
            8,
            Some(0.0),
            "N·m",
            Some("current_sense.zero_count"),
        ),
    ]
}

/// The options of `pts calibrate`.
#[derive(Clone, Debug)]
pub struct Args {
    /// The free sweep (CSV): read, or written with `simulate`.
    pub trace: PathBuf,
    /// The touch against the post (CSV): read, or written with `simulate`.
    pub touch: Option<PathBuf>,
    /// The closing onto the distal post (CSV): read, or written with `simulate`.
    pub tip_touch: Option<PathBuf>,
    /// θ1 of the post (rad); default: the touch trace's `# pts-calibrate` line.
    pub post_theta1_rad: Option<f64>,
    /// Distance of the post from O1 (m); default: the touch trace's line, else 0.7·l1.
    pub post_k1_m: Option<f64>,
    /// The nominal finger file the sweep was recorded with.
    pub finger: Option<PathBuf>,
    /// Where to write the calibrated finger file.
    pub out: Option<PathBuf>,
    /// JSON output.
    pub json: bool,
    /// Record the sweep(s) on the plant instead of identifying.
    pub simulate: bool,
    /// The plant's perturbation from the file (with `simulate`).
    pub perturb: String,
    /// Largest torque of the sweep (N·m, with `simulate`).
    pub safe_torque_nm: f64,
    /// Where to write the perturbed finger's true file (with `simulate`).
    pub truth_out: Option<PathBuf>,
    /// With `simulate`: run the firmware's sweep (`grasp::calibrate` with the firmware's
    /// sensors and torque loop) instead of the plant's ideal current ramp with dither.
    pub firmware: bool,
}

const POST_LINE: &str = "# pts-calibrate";

fn meta(text: &str, key: &str) -> Option<f64> {
    let line = text.lines().take(5).find(|l| l.starts_with(POST_LINE))?;
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(key)?.strip_prefix('='))
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| v.is_finite())
}

fn post_from_text(text: &str) -> (Option<f64>, Option<f64>) {
    let Some(line) = text.lines().take(5).find(|l| l.starts_with(POST_LINE)) else {
        return (None, None);
    };
    let get = |k: &str| {
        line.split_whitespace()
            .find_map(|w| w.strip_prefix(k)?.strip_prefix('='))
            .and_then(|v| v.parse::<f64>().ok())
            .filter(|v| v.is_finite())
    };
    (get("post_theta1_rad"), get("post_k1_m"))
}

/// Writes recorded rows as a trace CSV (`head`: a comment line first).
pub fn write_rows(path: &Path, head: Option<String>, rows: &[TraceRow]) -> Result<(), String> {
    let file = std::fs::File::create(path)
        .map_err(|e| format!("cannot create {}: {e}", path.display()))?;
    let mut w = std::io::BufWriter::new(file);
    let r = match head {
        Some(h) => writeln!(w, "{h}"),
        None => Ok(()),
    };
    r.and_then(|()| crate::trace::write_csv(rows, &mut w))
        .and_then(|()| w.flush())
        .map_err(|e| format!("writing {}: {e}", path.display()))
}

fn read_rows(path: &Path, file: &FingerFile) -> Result<(String, Vec<TraceRow>), String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let conv = |i: f64| file.torque_from_current(i);
    let tr =
        crate::trace::read_csv(&text, &conv).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok((text, tr.to_rows()))
}

/// Runs `pts calibrate`.
pub fn run(a: &Args) -> Result<(), String> {
    let nominal = crate::load_finger(a.finger.as_deref())?;
    let default_post = Post {
        theta1_rad: nominal.finger.theta01 + 0.45,
        k1_m: 0.7 * nominal.finger.l1,
    };
    if a.simulate {
        let pert = crate::sweep::Perturbation::parse(&a.perturb)?;
        let scene = pert.scene(plant::Scene::DEFAULT, &nominal)?;
        let plan = crate::sweep::SweepPlan {
            safe_torque_nm: a.safe_torque_nm,
            ..crate::sweep::SweepPlan::DEFAULT
        };
        let fw_cfg = grasp::calibrate::SweepConfig {
            safe_torque_unm: (a.safe_torque_nm * 1e6).round().clamp(0.0, 2e6) as i32,
            ..grasp::calibrate::SweepConfig::DEFAULT
        };
        let rec = |object: Option<plant::Object>| -> Result<Vec<TraceRow>, String> {
            if a.firmware {
                let (rows, phase) =
                    crate::sweep::record_firmware(&scene, &nominal, fw_cfg, object)?;
                if phase != grasp::calibrate::Phase::Done {
                    return Err(format!("the firmware's sweep ended {phase:?}"));
                }
                Ok(rows)
            } else {
                crate::sweep::record_object(&scene, &nominal, &plan, object)
            }
        };
        let rows = rec(None)?;
        write_rows(&a.trace, None, &rows)?;
        eprintln!("wrote {} ({} rows)", a.trace.display(), rows.len());
        if let Some(path) = &a.touch {
            let post = Post {
                theta1_rad: a.post_theta1_rad.unwrap_or(default_post.theta1_rad),
                k1_m: a.post_k1_m.unwrap_or(default_post.k1_m),
            };
            let rows = rec(Some(post.object()))?;
            let head = format!(
                "{POST_LINE} post_theta1_rad={} post_k1_m={}",
                post.theta1_rad, post.k1_m
            );
            write_rows(path, Some(head), &rows)?;
            eprintln!("wrote {} ({} rows)", path.display(), rows.len());
        }
        if let Some(path) = &a.tip_touch {
            let dp = DistalPost::for_file(&nominal, nominal.finger.theta01 + 0.35, 0.5)?;
            let rows = rec(Some(dp.object()))?;
            let head = format!(
                "{POST_LINE} tip_post_x_m={} tip_post_y_m={}",
                dp.x_m, dp.y_m
            );
            write_rows(path, Some(head), &rows)?;
            eprintln!("wrote {} ({} rows)", path.display(), rows.len());
        }
        if let Some(path) = &a.truth_out {
            let mut truth = pert.apply_to_file(&nominal);
            truth.name = format!("{} (plant truth: {})", nominal.name, a.perturb);
            std::fs::write(path, truth.to_toml_string())
                .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
            eprintln!("wrote {}", path.display());
        }
        return Ok(());
    }
    let (_, sweep) = read_rows(&a.trace, &nominal)?;
    let touch = match &a.touch {
        None => None,
        Some(path) => {
            let (text, rows) = read_rows(path, &nominal)?;
            let (t1, k1) = post_from_text(&text);
            let theta1_rad = a.post_theta1_rad.or(t1).ok_or_else(|| {
                format!(
                    "{}: no `{POST_LINE} post_theta1_rad=…` line: give --post-theta1-rad",
                    path.display()
                )
            })?;
            let k1_m = a.post_k1_m.or(k1).unwrap_or(default_post.k1_m);
            Some((rows, Post { theta1_rad, k1_m }))
        }
    };
    let tip = match &a.tip_touch {
        None => None,
        Some(path) => {
            let (text, rows) = read_rows(path, &nominal)?;
            let (Some(x_m), Some(y_m)) = (meta(&text, "tip_post_x_m"), meta(&text, "tip_post_y_m"))
            else {
                return Err(format!(
                    "{}: no `{POST_LINE} tip_post_x_m=… tip_post_y_m=…` line",
                    path.display()
                ));
            };
            Some((rows, DistalPost { x_m, y_m }))
        }
    };
    let cal = identify_with(
        &sweep,
        touch.as_ref().map(|(r, p)| (r.as_slice(), *p)),
        tip.as_ref().map(|(r, p)| (r.as_slice(), *p)),
        &nominal,
    )
    .map_err(|e| match torque_frame_error(&sweep, &nominal) {
        Some(frame) => format!("{}: {frame} (the identification: {e})", a.trace.display()),
        None => format!("{}: {e}", a.trace.display()),
    })?;
    report(&cal, &a.trace, a.out.as_deref(), a.json)
}

/// Why a sweep that could not be identified may be in another torque unit or sign: its
/// closing against the nominal finger's free motion ([`crate::offline::check_torque_frame`]),
/// as `torque_frame (…)`. Asked only of a sweep that failed: a finger far off its nominal
/// file moves the ratio too.
fn torque_frame_error(sweep: &[TraceRow], nominal: &FingerFile) -> Option<String> {
    let m = pts::Model::<f64>::new(&nominal.finger).ok()?;
    let rows: Vec<crate::offline::TraceSample> = sweep
        .iter()
        .map(|r| crate::offline::TraceSample {
            t_s: r.t_s,
            theta_a_rad: r.theta_a_rad,
            torque_nm: r.torque_nm,
        })
        .collect();
    let e = crate::offline::check_torque_frame(&m, &rows).err()?;
    Some(format!("{} ({e})", e.kind()))
}

/// Prints an identification (each parameter with its σ, the residual, what the recordings
/// could not separate) and writes the calibrated finger file to `out` when given; `source`
/// names the recording in the file's comment.
pub fn report(
    cal: &Calibration,
    source: &Path,
    out: Option<&Path>,
    json: bool,
) -> Result<(), String> {
    if let Some(path) = out {
        let mut text = format!(
            "# Calibrated by `pts calibrate` from {} (residual RMS {:.5} N·m).\n",
            source.display(),
            cal.residual_rms_nm
        );
        text += &cal.file.to_toml_string();
        std::fs::write(path, text).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    if json {
        crate::outln!("{}", cal.to_json());
    } else {
        crate::outln!("{}", cal.to_string().trim_end());
    }
    Ok(())
}
