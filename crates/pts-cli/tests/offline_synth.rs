//! `pts_cli::offline` on traces synthesized here from MODEL.md's quasi-static relations: free
//! motion (T_a = K1(θ1 − θ0,1), K2(θ2 − θ0,2) = T_a x2), then a vertex fixed in the world where
//! the free finger touched it at θ1,c = 1.2797 rad (the Table 2 contact configuration), the
//! contact sliding along the distal phalanx with the statics
//! T_a = K1(θ1 − θ0,1) + f (l1 cos θ2 + k2), T_a x2 = K2(θ2 − θ0,2) + f k2.
//! To that: a Coulomb offset (+F while loading, −F while unloading), encoder quantization,
//! ADC quantization and Gaussian current noise. Truth: the k2 of the vertex at contact.
//!
//! Also: several contacts in one file, unsorted and duplicated rows, 1 kHz and 10 kHz.
//! `cargo test --release -p pts-cli --test offline_synth -- --nocapture` prints the tables.

use grasp::{run_estimate_fw, Estimator};
use pts::Model;
use pts_cli::offline::{
    find_contact, for_each_contact, make_blocks, Block, OfflineConfig, OfflineError, TraceSample,
};

const L1: f64 = 0.100;
const L2: f64 = 0.075;
const K1: f64 = 0.6895;
const K2: f64 = 1.0274;
const THETA01: f64 = core::f64::consts::FRAC_PI_4;
const THETA1_C: f64 = 1.2797;
/// Encoder step (rad) and ADC torque step (N·m) of the paper's drive.
const QUANTUM: f64 = core::f64::consts::TAU / (64.0 * 3072.0);
const ADC_NM: f64 = 3.3 / (0.5 * 10.0 * 4096.0) * 4.5e-3 * 3072.0 * 0.6175;

/// A vertex at a world point, touched by the distal phalanx at θ1,c.
struct Vertex {
    px: f64,
    py: f64,
    ta_c: f64,
}

fn model() -> Model<f64> {
    Model::<f64>::paper().unwrap()
}

fn vertex(m: &Model<f64>, k2c: f64) -> Vertex {
    let ta_c = K1 * (THETA1_C - THETA01);
    let c = m.free_from_torque(ta_c).unwrap();
    assert!((c.theta1 - THETA1_C).abs() < 1e-9);
    let a = THETA1_C + c.theta2;
    Vertex {
        px: L1 * THETA1_C.cos() + k2c * a.cos(),
        py: L1 * THETA1_C.sin() + k2c * a.sin(),
        ta_c,
    }
}

/// The contact path at θ1 ≤ θ1,c: (θa, T_a, k2).
fn on_path(m: &Model<f64>, v: &Vertex, theta1: f64) -> (f64, f64, f64) {
    let (ox, oy) = (L1 * theta1.cos(), L1 * theta1.sin());
    let (dx, dy) = (v.px - ox, v.py - oy);
    let k2 = (dx * dx + dy * dy).sqrt();
    let theta2 = dy.atan2(dx) - theta1;
    let x2 = m.closure(theta2).unwrap().x2;
    let j1 = L1 * theta2.cos() + k2;
    // Eliminate f: T_a (k2 − x2 j1) = K1(θ1 − θ0,1) k2 − K2 θ2 j1.
    let ta = (K1 * (theta1 - THETA01) * k2 - K2 * theta2 * j1) / (k2 - x2 * j1);
    (m.theta_a(theta1, theta2).unwrap(), ta, k2)
}

/// Finger θa for an actuator torque T (N·m) with the vertex in place.
fn theta_a_at(m: &Model<f64>, v: &Vertex, t: f64) -> f64 {
    if t <= v.ta_c {
        return m.free_from_torque(t).unwrap().theta_a;
    }
    // Pressing on the vertex, θ1 goes back while θ2 closes: T_a rises as θ1 falls.
    let (mut lo, mut hi) = (THETA1_C - 0.3, THETA1_C);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if on_path(m, v, mid).1 < t {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    on_path(m, v, 0.5 * (lo + hi)).0
}

/// Deterministic noise (xorshift + Box–Muller).
struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (core::f64::consts::TAU * b).cos()
    }
}

/// How the measurement is spoiled.
#[derive(Clone, Copy)]
struct Spoil {
    /// Coulomb offset of the measured torque while moving (N·m).
    coulomb_nm: f64,
    /// Current noise, as torque σ (N·m).
    noise_nm: f64,
    /// Quantize θa and T_a like the encoder and the ADC.
    quantize: bool,
}

const REALISTIC: Spoil = Spoil {
    coulomb_nm: 0.05,
    noise_nm: 0.004,
    quantize: true,
};

/// Reflected drive inertia at the base link (kg·m²): 7e-9 × 3072².
const J_KGM2: f64 = 7.0e-9 * 3072.0 * 3072.0;
/// Half-width of the second difference for the inertial torque (s).
const H_S: f64 = 0.05;

/// ΔT_a ramp duration (s).
const RAMP_S: f64 = 1.0;

/// One grasp: free motion from 0.30 N·m at 0.02 N·m/s, contact, ΔT_a as a ramp 0.3 s after
/// contact, hold, then unload at 0.5 N·m/s back to 0.30 N·m and wait 0.5 s.
fn grasp_rows(
    m: &Model<f64>,
    v: &Vertex,
    dta: f64,
    dt: f64,
    t0: f64,
    sp: Spoil,
    rng: &mut Rng,
) -> Vec<TraceSample> {
    // Slow approach (0.02 N·m/s from 0.30 N·m) and a C¹ loading profile (cubic Hermite from
    // the approach slope to a flat top over RAMP_S): the actuator has inertia, and an
    // estimator that corrects for it (the path fit) must not see velocity jumps the
    // quasi-static synthesis cannot show the torque of.
    let (t_start, rate) = (0.30, 0.02);
    let t_contact = (v.ta_c - t_start) / rate;
    let t_step = t_contact + 0.3;
    let top = v.ta_c + dta;
    let from = t_start + rate * t_step;
    let t_unload = t_step + RAMP_S + 1.0;
    let t_free_again = t_unload + (top - t_start) / 0.5;
    let t_end = t_free_again + 0.5;
    // True actuator torque, and the friction sign (+ loading, − unloading, 0 held).
    let torque_at = |t: f64| -> (f64, f64) {
        if t < t_step {
            (t_start + rate * t, 1.0)
        } else if t < t_unload {
            let x = ((t - t_step) / RAMP_S).min(1.0);
            let (h00, h10, h01) = (
                2.0 * x * x * x - 3.0 * x * x + 1.0,
                x * x * x - 2.0 * x * x + x,
                -2.0 * x * x * x + 3.0 * x * x,
            );
            (
                h00 * from + h10 * RAMP_S * rate + h01 * top,
                if x < 1.0 { 1.0 } else { 0.0 },
            )
        } else if t < t_free_again {
            (top - 0.5 * (t - t_unload), -1.0)
        } else {
            (t_start, 0.0)
        }
    };
    let mut rows = vec![];
    let mut k = 0u64;
    loop {
        let t = k as f64 * dt;
        if t > t_end {
            break;
        }
        let (tt, dir) = torque_at(t);
        let th = theta_a_at(m, v, tt);
        // The drive's reflected inertia (rotor × N², ≈0.066 kg·m²) takes J·θ̈a of the motor
        // torque: central second difference over ±H_S (the contact kink becomes a short,
        // smooth impact instead of a Dirac).
        let theta_of = |t: f64| theta_a_at(m, v, torque_at(t).0);
        let acc = (theta_of(t + H_S) - 2.0 * th + theta_of((t - H_S).max(0.0))) / (H_S * H_S);
        // Held: the offset stays where the motion left it (stiction).
        let f = if dir == 0.0 && t >= t_free_again {
            -sp.coulomb_nm
        } else if dir == 0.0 {
            sp.coulomb_nm
        } else {
            dir * sp.coulomb_nm
        };
        let mut tm = tt + f + J_KGM2 * acc + sp.noise_nm * rng.normal();
        let mut thm = th;
        if sp.quantize {
            tm = (tm / ADC_NM).round() * ADC_NM;
            thm = (th / QUANTUM).floor() * QUANTUM;
        }
        rows.push(TraceSample {
            t_s: t0 + t,
            theta_a_rad: thm,
            torque_nm: tm,
        });
        k += 1;
    }
    rows
}

fn estimates(rows: &[TraceSample], est: Estimator) -> Vec<Result<f64, String>> {
    let m = model();
    let mfx = Model::<grasp::EstReal>::paper().unwrap();
    let cfg = OfflineConfig::DEFAULT.with_estimator(est);
    let mut scratch = vec![Block::default(); 1 << 15];
    let (nb, bs) = match make_blocks(&m, &cfg, rows, &mut scratch) {
        Ok(x) => x,
        Err(e) => return vec![Err(e.kind().into())],
    };
    let mut out = vec![];
    for_each_contact(&m, &cfg, &scratch[..nb], bs, QUANTUM, |r| {
        out.push(match r {
            Ok(seg) => match run_estimate_fw(
                &pts::Finger::PAPER,
                &grasp::DriveConfig::DEFAULT,
                &mfx,
                &seg.request,
            ) {
                Ok(r) => r
                    .k2_um
                    .map(|k| f64::from(k) * 1e-6)
                    .ok_or(format!("{:?}", r.located)),
                Err(e) => Err(e.kind().into()),
            },
            Err(e) => Err(e.kind().into()),
        })
    });
    out
}

fn err_pct(r: &Result<f64, String>, truth: f64) -> f64 {
    match r {
        Ok(k) => (k - truth) / L2 * 100.0,
        Err(e) => panic!("no estimate: {e}"),
    }
}

#[test]
fn synthesized_vertex_grid() {
    let m = model();
    println!("\nsynthesized from MODEL.md (vertex, Coulomb ±0.05 N·m, σ 4 mN·m, quantized), 10 kHz and 1 kHz");
    println!("| rate | ΔT_a (N·m) | k2,c/l2 | two-point err (% l2) | path fit err (% l2) |");
    println!("|---|---|---|---|---|");
    let (mut max2, mut maxf) = (0.0f64, 0.0f64);
    for dt in [1e-4, 1e-3] {
        for dta in [0.2, 0.5] {
            for kf in [0.2, 0.4, 0.6, 0.8] {
                let v = vertex(&m, kf * L2);
                let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ (kf * 1e3) as u64);
                let rows = grasp_rows(&m, &v, dta, dt, 0.0, REALISTIC, &mut rng);
                let tp = estimates(&rows, Estimator::TwoPoint);
                let pf = estimates(&rows, Estimator::PathFit);
                assert_eq!(tp.len(), 1, "one contact: {tp:?}");
                if tp[0].is_err() || pf[0].is_err() {
                    println!("| {dt} | {dta} | {kf} | {:?} | {:?} |", tp[0], pf[0]);
                    continue;
                }
                let (e2, ef) = (err_pct(&tp[0], kf * L2), err_pct(&pf[0], kf * L2));
                println!(
                    "| {} kHz | {dta} | {kf} | {e2:+.2} | {ef:+.2} |",
                    (1e-3 / dt).round()
                );
                max2 = max2.max(e2.abs());
                maxf = maxf.max(ef.abs());
            }
        }
    }
    println!("max |error|: two-point {max2:.2} % l2, path fit {maxf:.2} % l2");
    // The two-point method's own ΔT_a bias for a vertex (MODEL.md: 1.7 % at 0.2 N·m, 8.5 %
    // at 0.8) plus the friction it cannot separate; the path fit models both.
    // Measured (see the table): two-point ≤ 4.9 % l2, path fit ≤ 2.8 % l2.
    assert!(max2 < 6.0, "two-point {max2}");
    assert!(maxf < 3.5, "path fit {maxf}");
}

#[test]
fn several_contacts_in_one_file() {
    let m = model();
    let ks = [0.3 * L2, 0.7 * L2, 0.5 * L2];
    let mut rows: Vec<TraceSample> = vec![];
    let mut rng = Rng(7);
    for &k in &ks {
        let v = vertex(&m, k);
        let t0 = rows.last().map_or(0.0, |r| r.t_s + 1e-4);
        rows.extend(grasp_rows(&m, &v, 0.3, 1e-4, t0, REALISTIC, &mut rng));
    }
    let got = estimates(&rows, Estimator::PathFit);
    println!("\nthree grasps in one file (k2,c = 0.3, 0.7, 0.5 l2): {got:?}");
    assert_eq!(got.len(), 3, "{got:?}");
    for (g, &k) in got.iter().zip(&ks) {
        let e = err_pct(g, k);
        assert!(e.abs() < 2.0, "k2 {k}: {e} % l2");
    }
}

#[test]
fn unsorted_and_duplicated_rows() {
    let m = model();
    let v = vertex(&m, 0.4 * L2);
    let rows = grasp_rows(&m, &v, 0.3, 1e-4, 0.0, REALISTIC, &mut Rng(11));
    let base = estimates(&rows, Estimator::TwoPoint);
    // Unsorted: the core refuses with the row, sorted again it gives the same answer.
    let mut shuffled = rows.clone();
    let n = shuffled.len();
    shuffled[..n].rotate_left(n / 3);
    let mut scratch = vec![Block::default(); 1 << 15];
    let cfg = OfflineConfig::DEFAULT;
    assert_eq!(
        make_blocks(&m, &cfg, &shuffled, &mut scratch),
        Err(OfflineError::NonMonotoneTime {
            row: (n - n / 3) as u32
        })
    );
    shuffled.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    assert_eq!(estimates(&shuffled, Estimator::TwoPoint), base);
    // Every 5th row twice: same blocks up to the weights, same answer within 0.1 % l2.
    let mut dup = vec![];
    for (i, r) in rows.iter().enumerate() {
        dup.push(*r);
        if i % 5 == 0 {
            dup.push(*r);
        }
    }
    let d = estimates(&dup, Estimator::TwoPoint);
    let (a, b) = (base[0].clone().unwrap(), d[0].clone().unwrap());
    println!("\nduplicated rows: k2 {b:.6} vs {a:.6} m");
    assert!((a - b).abs() < 1e-3 * L2);
}

#[test]
fn typed_errors() {
    let m = model();
    let cfg = OfflineConfig::DEFAULT;
    let mut scratch = vec![Block::default(); 4096];
    assert_eq!(
        make_blocks(&m, &cfg, &[], &mut scratch),
        Err(OfflineError::TooShort)
    );
    let nan = [TraceSample {
        t_s: 0.0,
        theta_a_rad: f64::NAN,
        torque_nm: 0.0,
    }];
    assert_eq!(
        make_blocks(&m, &cfg, &nan, &mut scratch),
        Err(OfflineError::NonFinite { row: 0 })
    );
    // Free motion only: armed, no contact.
    let free: Vec<TraceSample> = (0..20000)
        .map(|k| {
            let t = 0.25 + 0.1 * k as f64 * 1e-4;
            TraceSample {
                t_s: k as f64 * 1e-4,
                theta_a_rad: m.free_from_torque(t).unwrap().theta_a,
                torque_nm: t + 0.02,
            }
        })
        .collect();
    let (nb, bs) = make_blocks(&m, &cfg, &free, &mut scratch).unwrap();
    assert_eq!(
        find_contact(&m, &cfg, &scratch[..nb], bs, 0.0, 0).map(|s| s.knee),
        Err(OfflineError::NoContact)
    );
    // Standing still under a rising torque (stiction, never moves): no free motion.
    let still: Vec<TraceSample> = (0..20000)
        .map(|k| TraceSample {
            t_s: k as f64 * 1e-4,
            theta_a_rad: -0.5,
            torque_nm: 0.3 + 1e-5 * k as f64,
        })
        .collect();
    let (nb, bs) = make_blocks(&m, &cfg, &still, &mut scratch).unwrap();
    assert_eq!(
        find_contact(&m, &cfg, &scratch[..nb], bs, 0.0, 0).map(|s| s.knee),
        Err(OfflineError::NoFreeMotion)
    );
    // A contact whose step is below the accepted minimum: refused as too small, with it.
    let v = vertex(&m, 0.5 * L2);
    let rows = grasp_rows(&m, &v, 0.3, 1e-4, 0.0, REALISTIC, &mut Rng(3));
    let strict = OfflineConfig {
        min_step_nm: 0.5,
        ..OfflineConfig::DEFAULT
    };
    let (nb, bs) = make_blocks(&m, &strict, &rows, &mut scratch).unwrap();
    match find_contact(&m, &strict, &scratch[..nb], bs, QUANTUM, 0).map(|s| s.knee) {
        Err(OfflineError::StepTooSmall { delta_ta_unm }) => {
            assert!((delta_ta_unm - 300_000).abs() < 50_000, "{delta_ta_unm}")
        }
        other => panic!("{other:?}"),
    }
}

/// Arbitrary data (random walks, jumps, constant stretches, huge values) never panics and
/// returns typed errors or segments; whatever is found is bounded.
#[test]
fn no_panic_on_arbitrary_traces() {
    let m = model();
    let cfg = OfflineConfig::DEFAULT;
    let mut scratch = vec![Block::default(); 2048];
    for seed in 1..40u64 {
        let mut rng = Rng(seed.wrapping_mul(0x2545_F491_4F6C_DD1D));
        let n = 200 + (rng.uniform() * 30000.0) as usize;
        let mut th = -0.85 + rng.uniform();
        let mut tq = rng.uniform();
        let mut t = 0.0;
        let rows: Vec<TraceSample> = (0..n)
            .map(|_| {
                t += if rng.uniform() < 0.1 {
                    0.0
                } else {
                    1e-4 * (1.0 + 10.0 * rng.uniform())
                };
                th += 1e-3 * rng.normal() + if rng.uniform() < 1e-3 { 1.0 } else { 0.0 };
                tq += 1e-2 * rng.normal() * if seed % 3 == 0 { 1e6 } else { 1.0 };
                TraceSample {
                    t_s: t,
                    theta_a_rad: th,
                    torque_nm: tq,
                }
            })
            .collect();
        if let Ok((nb, bs)) = make_blocks(&m, &cfg, &rows, &mut scratch) {
            let mfx = Model::<grasp::EstReal>::paper().unwrap();
            for_each_contact(&m, &cfg, &scratch[..nb], bs, QUANTUM, |r| {
                if let Ok(seg) = r {
                    let _ = run_estimate_fw(
                        &pts::Finger::PAPER,
                        &grasp::DriveConfig::DEFAULT,
                        &mfx,
                        &seg.request,
                    );
                    assert!(seg.request.path.len() <= grasp::PATH_CAPACITY);
                }
            });
        }
    }
}
