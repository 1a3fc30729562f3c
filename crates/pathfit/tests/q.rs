//! The firmware's integer path fit (`pathfit::q`) against the generic fit in f64.
use pathfit::q::{fit_path_q, PathTable, RawSample};
use pathfit::{fit_path, PathFitConfig, PathSample};
use pts::fixed::Fx32;
use pts::{Finger, Model, Real};

const TICK_S: f64 = 1e-4;

fn read_case(path: &str) -> (f64, f64, Vec<RawSample>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let head: Vec<f64> = lines
        .next()
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let samples = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            RawSample {
                tick: (v[0] / TICK_S).round() as u32,
                theta_a_urad: (v[1] * 1e6).round() as i32,
                torque_unm: (v[2] * 1e6).round() as i32,
            }
        })
        .collect();
    (head[0], head[1], samples)
}

#[test]
fn harness_cases_match_f64() {
    // The recorded-style requests of the instruction-count harness (realistic plant).
    let table = PathTable::new(&Finger::PAPER, &PathFitConfig::DEFAULT, TICK_S).unwrap();
    let m = Model::<f64>::paper().unwrap();
    // QCASES=dir runs another folder of case files (e.g. the grid dumped by PATHFIT_DUMP).
    let dir = std::env::var("QCASES")
        .unwrap_or(concat!(env!("CARGO_MANIFEST_DIR"), "/benches/icount/cases").to_string());
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        let (thc, tac, raw) = read_case(p.to_str().unwrap());
        let s64: Vec<PathSample<f64>> = raw
            .iter()
            .map(|s| PathSample {
                time_s: s.tick as f64 * TICK_S,
                theta_a_rad: s.theta_a_urad as f64 * 1e-6,
                torque_nm: s.torque_unm as f64 * 1e-6,
            })
            .collect();
        let f = fit_path(
            &m,
            &PathFitConfig::DEFAULT,
            thc,
            Some(tac),
            s64.iter().copied(),
        );
        let q = fit_path_q(
            &table,
            Fx32::from_f64(thc),
            Some(Fx32::from_f64(tac)),
            raw.iter().copied(),
        );
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with("refused_") {
            // A path that leaves the tip: both back ends refuse it, for the same reason.
            let (ef, eq) = (f.unwrap_err(), q.unwrap_err());
            println!("{name}: refused, f64 {} / q {}", ef.kind(), eq.kind());
            assert_eq!(ef, eq, "{name}");
            continue;
        }
        let (f, q) = (f.unwrap(), q.unwrap());
        println!(
            "{name}: k2 f64 {:.6} q {:.6} m, σ {:.6} / {:.6} m, R {:.5} / {:.5} m, evals {} / {}",
            f.k2_contact_m,
            q.k2_contact_m.to_f64(),
            f.sigma_k2_m,
            q.sigma_k2_m.to_f64(),
            f.radius_m,
            q.radius_m.to_f64(),
            f.path_evals,
            q.path_evals
        );
        // The same fit: LM stops within a tenth of σ in χ² terms, so the two back ends agree
        // to a fraction of σ (not to rounding); σ itself to a few per cent.
        let sig = f.sigma_k2_m;
        let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol;
        assert!(
            close(q.k2_contact_m.to_f64(), f.k2_contact_m, 0.1 * sig),
            "{name}: k2"
        );
        assert!(
            close(q.k2_final_m.to_f64(), f.k2_final_m, 0.2 * sig),
            "{name}: k2 final"
        );
        assert!(close(q.sigma_k2_m.to_f64() / sig, 1.0, 0.05), "{name}: σ");
        assert_eq!(q.object, f.object, "{name}");
        assert!(
            close(
                q.radius_m.to_f64(),
                f.radius_m,
                0.2 * f.sigma_radius_m + 1e-6
            ),
            "{name}: R"
        );
        assert!(
            close(
                q.theta_a_c_rad.to_f64(),
                f.theta_a_c_rad,
                0.2 * f.sigma_theta_a_c_rad
            ),
            "{name}: θa,c"
        );
    }
}

mod arbitrary {
    //! The integer kernel on inputs no controller produces: it must answer Ok with a located
    //! contact on the phalanx or a typed error, never panic (the test profile checks overflow).
    use super::*;
    use proptest::prelude::*;

    fn table() -> PathTable {
        PathTable::new(&Finger::PAPER, &PathFitConfig::DEFAULT, TICK_S).unwrap()
    }

    fn check(r: Result<pathfit::PathFit<Fx32>, pathfit::PathFitError>) {
        if let Ok(f) = r {
            let k2 = f.k2_contact_m.to_f64();
            assert!(k2 > 0.0 && k2 <= Finger::PAPER.l2, "k2 {k2}");
            assert!(f.sigma_k2_m.to_f64() > 0.0, "σ {:?}", f.sigma_k2_m);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        #[test]
        fn arbitrary_words(
            thc in any::<i64>(),
            tac in any::<i64>(),
            raw in proptest::collection::vec((any::<u32>(), any::<i32>(), any::<i32>()), 0..64),
        ) {
            let s = raw.iter().map(|&(t, th, tq)| RawSample { tick: t, theta_a_urad: th, torque_unm: tq });
            check(fit_path_q(&table(), Fx32::from_bits(thc), Some(Fx32::from_bits(tac)), s));
        }

        /// Samples in the working range (contact angle, θa above it, torques, increasing
        /// ticks with repeats) but otherwise random: the fit runs on them.
        #[test]
        fn random_paths_in_range(
            thc in -1.3f64..1.9,
            tac in -0.5f64..2.0,
            raw in proptest::collection::vec((0u32..60, 0i32..300_000, -2_000_000i32..3_000_000), 0..120),
        ) {
            let base = (thc * 1e6) as i32;
            let mut tick = 0u32;
            let s: Vec<RawSample> = raw.iter().map(|&(dt, dth, tq)| {
                tick += dt;
                RawSample { tick, theta_a_urad: base + dth, torque_unm: tq }
            }).collect();
            check(fit_path_q(&table(), Fx32::from_f64(thc), Some(Fx32::from_f64(tac)), s.iter().copied()));
        }

        /// A recorded request with noise, spikes, repeated and reordered ticks, a truncated
        /// end and a shifted contact angle: deep into the fit, never a panic.
        #[test]
        fn perturbed_request(
            seed in any::<u64>(),
            noise_urad in 0i32..2000,
            noise_unm in 0i32..200_000,
            spike in any::<(usize, i32)>(),
            keep in 5usize..140,
            dth_c in -0.05f64..0.05,
            tick_jitter in 0u32..3,
        ) {
            let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/icount/cases");
            let (thc, tac, raw) = read_case(&format!("{dir}/table2_realistic.txt"));
            let mut x = seed | 1;
            let mut rnd = move |m: i32| {
                x ^= x << 13; x ^= x >> 7; x ^= x << 17;
                if m == 0 { 0 } else { (x % (2 * m as u64 + 1)) as i32 - m }
            };
            let mut s: Vec<RawSample> = raw.iter().take(keep).map(|r| RawSample {
                tick: r.tick.wrapping_add(rnd(tick_jitter as i32) as u32),
                theta_a_urad: r.theta_a_urad.saturating_add(rnd(noise_urad)),
                torque_unm: r.torque_unm.saturating_add(rnd(noise_unm)),
            }).collect();
            if let Some(v) = s.get_mut(spike.0 % keep.max(1)) {
                v.torque_unm = spike.1;
            }
            check(fit_path_q(&table(), Fx32::from_f64(thc + dth_c), Some(Fx32::from_f64(tac)), s.iter().copied()));
        }
    }
}
