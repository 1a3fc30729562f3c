//! `pts estimate` on grasps recorded by two simulators that share no code with this
//! project (`tests/data/traces`, README there): the code path the command runs on a CSV
//! without a `# pts-sim` line (`trace::read_csv` → `replay::segment`), scored against each
//! recording's ground truth (`truth.k2_c_m`, the first contact).
//!
//! `cargo test --release -p pts-cli --test foreign_traces -- --nocapture` prints the table.

use pts_cli::method::Method;
use pts_cli::replay::{segment, Segmented};
use serde_json::Value;
use std::path::{Path, PathBuf};

const L2: f64 = 0.075;
/// Bounds asserted on the path fit's error (% of l2): the issue's, a mean ≤ 1.5 and a max ≤ 4
/// with every distal positive answered and the true error within 3σ (σ carries the contact
/// friction the path cannot show).
const MEAN_BOUND: f64 = 1.5;
const MAX_BOUND: f64 = 4.0;
/// Distal positives the path fit must answer: all of them.
const MIN_ANSWERED: usize = 24;

/// Another directory of recordings with the same truth files (e.g. the engine grid written by
/// `cargo run -p dynsim --release -- --out DIR --grid full`): its table is printed, the
/// bounds below are not asserted. The bad-recording tests keep using the committed samples.
const DIR_ENV: &str = "FOREIGN_TRACES_DIR";

/// The committed sample recordings.
fn samples_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/traces")
}

/// The recordings the table is made of.
fn dir() -> PathBuf {
    std::env::var(DIR_ENV).map_or_else(|_| samples_dir(), PathBuf::from)
}

fn ids() -> Vec<String> {
    ids_in(&dir())
}

/// The recordings in `dir` that have a truth file beside them, sorted.
fn ids_in(dir: &std::path::Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| {
            let p = e.ok()?.path();
            let stem = p.file_stem()?.to_string_lossy().into_owned();
            (p.extension()? == "csv" && p.with_extension("json").exists()).then_some(stem)
        })
        .collect();
    v.sort();
    v
}

/// The committed samples (what [`rows`] reads), whatever `FOREIGN_TRACES_DIR` names.
fn sample_ids() -> Vec<String> {
    ids_in(&samples_dir())
}

/// The command's path on CSV text.
fn run_text(text: &str, method: Method) -> Result<Segmented, String> {
    let file = pts::config::FingerFile::paper();
    let tr = pts_cli::trace::read_csv(text, &|i| file.torque_from_current(i))?;
    segment(&tr, &file, method).map_err(|e| e.to_string())
}

fn truth(dir: &Path, id: &str) -> Value {
    let t = std::fs::read_to_string(dir.join(format!("{id}.json"))).unwrap();
    serde_json::from_str(&t).unwrap()
}

/// `FOREIGN_TRACES_SHIFT_S=S`: every row's time S seconds later (the same recordings from a
/// logger started earlier). The estimate should not move with the time origin; it does, by the
/// rounding of which block a row on a block boundary falls in (RESULTS, "Open work").
const SHIFT_ENV: &str = "FOREIGN_TRACES_SHIFT_S";

fn csv(dir: &Path, id: &str) -> String {
    let text = std::fs::read_to_string(dir.join(format!("{id}.csv"))).unwrap();
    let Some(shift) = std::env::var(SHIFT_ENV)
        .ok()
        .map(|v| v.parse::<f64>().expect("FOREIGN_TRACES_SHIFT_S: seconds"))
    else {
        return text;
    };
    let mut lines = text.lines();
    let header = lines.next().unwrap_or_default();
    std::iter::once(header.to_string())
        .chain(lines.map(|l| match l.split_once(',') {
            Some((t, rest)) => match t.parse::<f64>() {
                Ok(t) => format!("{:.6},{rest}", t + shift),
                Err(_) => l.to_string(),
            },
            None => l.to_string(),
        }))
        .flat_map(|l| [l, "\n".to_string()])
        .collect()
}

/// One row of the table: (answer, k̂2 m, σ m, error % l2) for a method.
struct Answer {
    phalanx: String,
    k2: Option<f64>,
    sigma: Option<f64>,
}

fn answer(seg: &Result<Segmented, String>, two_point: bool) -> Answer {
    let none = |s: &str| Answer {
        phalanx: s.into(),
        k2: None,
        sigma: None,
    };
    let seg = match seg {
        Ok(s) => s,
        Err(e) => return none(&format!("error: {e}")),
    };
    let Some(c) = seg.contacts.first() else {
        return none(&format!(
            "none ({})",
            seg.errors.first().map_or("", |e| e.0)
        ));
    };
    let est = if two_point {
        c.two_point.as_ref().unwrap_or(&c.estimate)
    } else {
        &c.estimate
    };
    match est {
        Ok(r) => Answer {
            phalanx: pts_cli::trace::located_name(r.located).into(),
            k2: r.k2_um.map(|k| f64::from(k) * 1e-6),
            sigma: if two_point { None } else { c.sigma_k2_m },
        },
        Err(e) => none(&format!("refused: {}", e.kind)),
    }
}

struct Row {
    id: String,
    expected: String,
    k2_true: Option<f64>,
    pf: Answer,
    tp: Answer,
}

fn table() -> Vec<Row> {
    ids()
        .into_iter()
        .map(|id| {
            let t = truth(&dir(), &id);
            let seg = run_text(&csv(&dir(), &id), Method::Pathfit);
            Row {
                expected: t["expected"].as_str().unwrap().to_string(),
                k2_true: t["truth"]["k2_c_m"].as_f64(),
                pf: answer(&seg, false),
                tp: answer(&seg, true),
                id,
            }
        })
        .collect()
}

fn err_pct(a: &Answer, truth: Option<f64>) -> Option<f64> {
    Some((a.k2? - truth?) / L2 * 100.0)
}

fn fmt_mm(v: Option<f64>) -> String {
    v.map_or("—".into(), |v| format!("{:.2}", v * 1e3))
}

/// Every recording: distal positives answered within the bounds, the negatives right.
#[test]
fn foreign_traces_default_method() {
    let rows = table();
    println!(
        "| id | expected | path fit (default) | k̂2 mm | σ mm | k2,c truth mm | error % l2 | two-point | k̂2 mm | error % l2 |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let (mut errs, mut tp_errs, mut within3) = (vec![], vec![], 0usize);
    for r in &rows {
        let e = err_pct(&r.pf, r.k2_true);
        let et = err_pct(&r.tp, r.k2_true);
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.id,
            r.expected,
            r.pf.phalanx,
            fmt_mm(r.pf.k2),
            fmt_mm(r.pf.sigma),
            fmt_mm(r.k2_true),
            e.map_or("—".into(), |e| format!("{e:+.2}")),
            r.tp.phalanx,
            fmt_mm(r.tp.k2),
            et.map_or("—".into(), |e| format!("{e:+.2}")),
        );
        if r.expected == "distal" {
            if let Some(e) = e {
                errs.push(e.abs());
                if let Some(s) = r.pf.sigma {
                    if e.abs() * L2 / 100.0 <= 3.0 * s {
                        within3 += 1;
                    }
                }
            }
            if let Some(e) = et {
                tp_errs.push(e.abs());
            }
        }
    }
    let stats = |v: &[f64]| {
        (
            v.iter().sum::<f64>() / v.len().max(1) as f64,
            v.iter().copied().fold(0.0, f64::max),
        )
    };
    let (mean, max) = stats(&errs);
    let (tmean, tmax) = stats(&tp_errs);
    let positives = rows.iter().filter(|r| r.expected == "distal").count();
    println!(
        "path fit: {}/{positives} distal positives answered, mean {mean:.2} %, max {max:.2} % of l2,          true error within 3σ {within3}/{}",
        errs.len(),
        errs.len()
    );
    println!(
        "two-point: {}/{positives} answered, mean {tmean:.2} %, max {tmax:.2} % of l2",
        tp_errs.len()
    );
    if std::env::var(DIR_ENV).is_ok() {
        return;
    }
    // Negatives: no object → no contact; proximal → proximal.
    for r in rows.iter().filter(|r| r.expected != "distal") {
        match r.expected.as_str() {
            "none" => assert!(
                r.pf.phalanx.starts_with("none"),
                "{}: {}",
                r.id,
                r.pf.phalanx
            ),
            "proximal" => assert_eq!(r.pf.phalanx, "proximal", "{}", r.id),
            x => panic!("unknown expectation {x}"),
        }
    }
    assert!(
        errs.len() >= MIN_ANSWERED.min(positives),
        "answered {}",
        errs.len()
    );
    assert!(
        within3 == errs.len(),
        "true error within 3σ: {within3}/{}",
        errs.len()
    );
    assert!(
        mean <= MEAN_BOUND && max <= MAX_BOUND,
        "mean {mean:.2} % max {max:.2} %"
    );
}

/// (kind of the first refusal or the phalanx, k̂2 m) of the default method on CSV text.
fn outcome(text: &str) -> (String, Option<f64>) {
    match run_text(text, Method::Pathfit) {
        Err(e) => (e, None),
        Ok(seg) => match seg.contacts.first() {
            Some(c) => match &c.estimate {
                Ok(r) => (
                    pts_cli::trace::located_name(r.located).to_string(),
                    r.k2_um.map(|k| f64::from(k) * 1e-6),
                ),
                Err(e) => (e.kind.to_string(), None),
            },
            None => (
                seg.errors.first().map_or("no_contact", |e| e.0).to_string(),
                None,
            ),
        },
    }
}

/// CSV rows (t, θa, T) of a committed sample recording.
fn rows(id: &str) -> Vec<[f64; 3]> {
    csv(&samples_dir(), id)
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

fn to_csv(rows: &[[f64; 3]]) -> String {
    let mut s = String::from("t_s,theta_a_rad,torque_nm\n");
    for r in rows {
        s += &format!("{:.6},{:.8},{:.6}\n", r[0], r[1], r[2]);
    }
    s
}

const BAD_ID: &str = "dyn02_vtx_k58_mu02_dT06__default";

/// The answer is a continuous function of the recording: θa moved by ±1e-12 rad on every row
/// (far below any encoder, a change of the last bits of the block means) leaves each sample's
/// outcome and moves k̂2 by at most 5 µm. The segmenter's discrete choices (the crank turned
/// back or not, the grid angle of the contact's hinge) are taken on differences that the
/// rounding of the block means cannot decide.
#[test]
fn the_answer_does_not_hang_on_the_last_bits_of_theta() {
    let mut moved = 0.0f64;
    for id in sample_ids() {
        let clean = rows(&id);
        let (kind, k2) = outcome(&to_csv_exact(&clean));
        for d in [1e-12, -1e-12] {
            let r: Vec<[f64; 3]> = clean.iter().map(|x| [x[0], x[1] + d, x[2]]).collect();
            let (kind_d, k2_d) = outcome(&to_csv_exact(&r));
            assert_eq!(
                kind, kind_d,
                "{id} θa {d:+e}: {kind} {k2:?} → {kind_d} {k2_d:?}"
            );
            if let (Some(a), Some(b)) = (k2, k2_d) {
                assert!((a - b).abs() <= 5e-6, "{id} θa {d:+e}: k2 {a} → {b}");
                moved = moved.max((a - b).abs());
            }
        }
    }
    println!(
        "largest move of k2 under a ±1e-12 rad shift of θa: {:.1} µm",
        moved * 1e6
    );
}

/// The same recordings with their clock started elsewhere: every time shifted by a part of a
/// block, by hours, and to a Unix time (whose f64 holds times to 0.24 µs). Where the 4 ms
/// blocks begin follows the first row, and a row on a block boundary counts in the later
/// block whatever the rounding of its time, so each answer stays where it was.
#[test]
fn the_answer_does_not_depend_on_the_time_origin() {
    let samples = sample_ids();
    for (shift, bound) in [
        (0.0015, 1e-6),
        (0.5, 1e-6),
        (12_345.678, 1e-6),
        (1.7e9, 2e-5),
    ] {
        let mut moved = 0.0f64;
        for id in &samples {
            let clean = rows(id);
            let (kind, k2) = outcome(&to_csv_exact(&clean));
            let r: Vec<[f64; 3]> = clean.iter().map(|x| [x[0] + shift, x[1], x[2]]).collect();
            let (kind_s, k2_s) = outcome(&to_csv_exact(&r));
            assert_eq!(
                kind, kind_s,
                "{id} t + {shift} s: {kind} {k2:?} → {kind_s} {k2_s:?}"
            );
            if let (Some(a), Some(b)) = (k2, k2_s) {
                moved = moved.max((a - b).abs());
            }
        }
        println!(
            "time origin + {shift} s: k2 moves by at most {:.1} µm",
            moved * 1e6
        );
        assert!(moved <= bound, "t + {shift} s: k2 moved {moved:e} m");
    }
}

/// Rows as CSV with every digit f64 needs (round trip exact).
fn to_csv_exact(rows: &[[f64; 3]]) -> String {
    let mut s = String::from("t_s,theta_a_rad,torque_nm\n");
    for r in rows {
        s += &format!("{:?},{:?},{:?}\n", r[0], r[1], r[2]);
    }
    s
}

/// A single θa row off by 0.5 rad (during the step, or in the approach): refused, never
/// answered.
#[test]
fn outlier_row_is_refused() {
    let clean = rows(BAD_ID);
    let truth = truth(&samples_dir(), BAD_ID)["truth"]["t_contact_s"]
        .as_f64()
        .unwrap();
    for t_spike in [truth - 0.3, truth + 0.1] {
        let mut r = clean.clone();
        let i = r.iter().position(|x| x[0] >= t_spike).unwrap();
        r[i][1] += 0.5;
        let (kind, k2) = outcome(&to_csv(&r));
        println!("spike at t = {t_spike:.3} s: {kind} {k2:?}");
        assert!(
            k2.is_none(),
            "a corrupted row must not be answered: {kind} {k2:?}"
        );
        assert!(kind.contains("outlier_sample"), "{kind}");
    }
}

/// 1000 s at rest before the grasp: the same answer as without. The idle is cut to the 2 s
/// before the first motion, and where the blocks begin follows the rows, not the clock
/// (measured 0 µm apart, the extra rest leaving the approach's identification as it was;
/// before block boundaries were independent of the time origin, 1.15 % of l2, 0.4σ).
#[test]
fn long_idle_before_the_grasp() {
    let clean = rows(BAD_ID);
    let (k0, a0) = outcome(&to_csv(&clean));
    let idle = 1000.0;
    let n_idle = (idle * 1e3) as usize;
    let mut r: Vec<[f64; 3]> = (0..n_idle)
        .map(|i| [i as f64 * 1e-3, clean[0][1], clean[0][2]])
        .collect();
    r.extend(clean.iter().map(|x| [x[0] + idle, x[1], x[2]]));
    let (k1, a1) = outcome(&to_csv(&r));
    println!("idle 1000 s: {k1} {a1:?} (without: {k0} {a0:?})");
    assert_eq!(k0, k1);
    let (a0, a1) = (a0.unwrap(), a1.unwrap());
    let sigma = run_text(&to_csv(&clean), Method::Pathfit)
        .ok()
        .and_then(|s| s.contacts.first()?.sigma_k2_m)
        .expect("σ of the answer");
    println!(
        "{:.2} % of l2 apart, {:.2}σ",
        (a0 - a1).abs() / L2 * 100.0,
        (a0 - a1).abs() / sigma
    );
    assert!((a0 - a1).abs() <= 1e-6, "{a0} vs {a1} (σ {sigma})");
}

/// Decimated to 100 Hz: refused (the contact cannot be placed), never answered.
#[test]
fn decimated_to_100_hz_is_refused() {
    let r: Vec<[f64; 3]> = rows(BAD_ID).into_iter().step_by(10).collect();
    let (kind, k2) = outcome(&to_csv(&r));
    println!("100 Hz: {kind} {k2:?}");
    assert!(k2.is_none());
    assert!(kind.contains("sample_rate_too_low"), "{kind}");
    // 250 Hz is still accepted and answered.
    let r: Vec<[f64; 3]> = rows(BAD_ID).into_iter().step_by(4).collect();
    let (kind, k2) = outcome(&to_csv(&r));
    println!("250 Hz: {kind} {k2:?}");
    assert_eq!(kind, "distal");
}

/// A fixed generator of uniform draws in [0, 1) (a 64-bit LCG's upper bits): the disturbed
/// recordings are the same on every run.
fn uniform_from(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The noise-free samples with their row times disturbed three ways, drawn by a fixed
/// generator: stamped with ±0.2 ms of jitter by the logger (read at their grid's times, so the
/// answer is the clean one's), sampled at times that jitter by ±0.2 ms (θa and torque
/// interpolated there), and with one row in ten dropped. Every one is answered on the distal
/// phalanx, within 3σ of the truth. A logger's timing should not decide whether a clean grasp
/// is answered: read at the jittered stamps, the engine grid answered 84.8 % of its grasps
/// instead of 97.8 % (RESULTS); and before the fit's normal matrix was formed as a Gram matrix, its
/// rounding made it indefinite on `qs01` (contact angle and friction offset nearly collinear)
/// and the thinned recording was refused as `not_determined`.
#[test]
fn a_clean_recording_is_answered_whatever_the_row_timing() {
    let mut uniform = uniform_from(0x2545_f491_4f6c_dd1d);
    let clean_ids: Vec<String> = sample_ids()
        .into_iter()
        .filter(|id| id.ends_with("__ideal"))
        .collect();
    assert!(clean_ids.len() >= 5, "noise-free samples: {clean_ids:?}");
    let mut moved = 0.0f64;
    for id in &clean_ids {
        let k2_true = truth(&samples_dir(), id)["truth"]["k2_c_m"]
            .as_f64()
            .unwrap();
        let clean = rows(id);
        let (_, k2_clean) = outcome(&to_csv_exact(&clean));
        let stamped: Vec<[f64; 3]> = clean
            .iter()
            .map(|x| [x[0] + (uniform() - 0.5) * 4e-4, x[1], x[2]])
            .collect();
        let last = clean.len() - 1;
        let sampled: Vec<[f64; 3]> = (0..=last)
            .map(|i| {
                let (a, b) = (clean[i.min(last - 1)], clean[(i + 1).min(last)]);
                let t =
                    clean[i][0] + (uniform() - 0.5) * 4e-4 * f64::from(u8::from(i > 0 && i < last));
                let f = (t - a[0]) / (b[0] - a[0]);
                [t, a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])]
            })
            .collect();
        let thinned: Vec<[f64; 3]> = clean
            .iter()
            .enumerate()
            .filter(|(i, _)| *i < 5 || uniform() >= 0.1)
            .map(|(_, x)| *x)
            .collect();
        for (what, r) in [
            ("stamped with ±0.2 ms of jitter", stamped),
            ("sampled at times jittered by ±0.2 ms", sampled),
            ("10 % of rows dropped", thinned),
        ] {
            let text = to_csv_exact(&r);
            let (kind, k2) = outcome(&text);
            let sigma = run_text(&text, Method::Pathfit)
                .ok()
                .and_then(|s| s.contacts.first()?.sigma_k2_m);
            println!(
                "{id}, {what}: {kind} {:?} % of l2 (σ {:?} %)",
                k2.map(|k| (k - k2_true) / L2 * 100.0),
                sigma.map(|s| s / L2 * 100.0)
            );
            assert_eq!(kind, "distal", "{id}, {what}");
            let (k2, sigma) = (k2.unwrap(), sigma.unwrap());
            assert!(
                (k2 - k2_true).abs() <= 3.0 * sigma,
                "{id}, {what}: k2 {k2} vs {k2_true} (σ {sigma})"
            );
            if what.starts_with("stamped") {
                let d = (k2 - k2_clean.unwrap()).abs();
                moved = moved.max(d);
                assert!(d <= 2e-5, "{id}, {what}: {k2} vs the clean {k2_clean:?}");
            }
        }
    }
    println!(
        "stamped with jitter: k2 within {:.1} µm of the clean recording's",
        moved * 1e6
    );
}

/// Every sample recording damaged as a logger or a sensor may damage one: a torque spike of
/// 0.5 N·m on one row (on the contact, or on the approach), 20 ms of rows lost (on the
/// contact, or on the approach), every 50th row logged twice, two rows swapped, the encoder
/// chattering by one count for 100 rows, five times the torque noise (σ 0.02 N·m), the torque
/// saturating at 0.7 N·m, the recording cut 0.1 s after the contact. Each is refused or
/// answered within 3σ of the truth: no distal contact read as proximal, no negative read as
/// distal, the cut recording refused, and a noisy recording whose torque went past 0.7 N·m
/// refused as `torque_saturated` (one had read as a proximal contact). A noise-free one
/// cannot show its saturation (a simulation's hold repeats its torque too). (A current sensor's offset drifting by 0.02 N·m over the
/// recording, or a torque column lagging θa by 5 ms, are not covered: the engine grid's
/// grasps so damaged read outside 3σ on a few per cent; RESULTS, "Open work".)
#[test]
fn a_damaged_recording_is_refused_or_answered_within_3_sigma() {
    type Damage = fn(&mut Vec<[f64; 3]>, usize, &mut dyn FnMut() -> f64);
    let damages: [(&str, Damage); 10] = [
        ("torque spike on the contact", |r, c, _| r[c + 15][2] += 0.5),
        ("torque spike on the approach", |r, c, _| {
            r[c - 100][2] += 0.5
        }),
        ("20 ms lost on the contact", |r, c, _| {
            r.drain(c + 30..c + 50);
        }),
        ("20 ms lost on the approach", |r, c, _| {
            r.drain(c - 80..c - 60);
        }),
        ("every 50th row twice", |r, _, _| {
            *r = r
                .iter()
                .enumerate()
                .flat_map(|(i, x)| std::iter::repeat_n(*x, 1 + usize::from(i % 50 == 7)))
                .collect();
        }),
        ("two rows swapped", |r, c, _| r.swap(c + 40, c + 41)),
        ("encoder chatter", |r, c, _| {
            let q = pts::config::FingerFile::paper().rad_per_count();
            for x in r.iter_mut().skip(c + 50).take(100).step_by(2) {
                x[1] += q;
            }
        }),
        ("5× torque noise", |r, _, gauss| {
            for x in r.iter_mut() {
                x[2] += 0.02 * gauss();
            }
        }),
        ("torque saturating at 0.7 N·m", |r, _, _| {
            for x in r.iter_mut() {
                x[2] = x[2].min(0.7);
            }
        }),
        ("cut 0.1 s after the contact", |r, c, _| r.truncate(c + 100)),
    ];
    let mut uniform = uniform_from(0x9e37_79b9_7f4a_7c15);
    // Box–Muller on the generator above (1 − u lies in (0, 1]).
    let mut gauss = move || {
        let (u, v) = (uniform(), uniform());
        (-2.0 * (1.0 - u).ln()).sqrt() * (2.0 * core::f64::consts::PI * v).cos()
    };
    let (mut answered, mut refused) = (0usize, 0usize);
    for id in sample_ids() {
        let t = truth(&samples_dir(), &id);
        let expected = t["expected"].as_str().unwrap().to_string();
        let k2_true = t["truth"]["k2_c_m"].as_f64();
        let clean = rows(&id);
        // The row of the first contact (a negative: where a grasp's contact would be).
        let t_c = t["truth"]["t_contact_s"].as_f64().unwrap_or(0.8);
        let c = clean.iter().position(|x| x[0] >= t_c).unwrap();
        for (what, damage) in damages {
            let mut r = clean.clone();
            damage(&mut r, c, &mut gauss);
            let a = answer(&run_text(&to_csv(&r), Method::Pathfit), false);
            let located = a.phalanx.as_str();
            // A noisy sensor held at one value names its saturation.
            let clipped = clean.iter().any(|x| x[2] > 0.7);
            if what.starts_with("torque saturating") && id.ends_with("__default") && clipped {
                assert!(located.contains("torque_saturated"), "{id}: {located}");
            }
            let read = matches!(located, "distal" | "proximal" | "proximal_or_near_o2");
            if !read {
                refused += 1;
                continue;
            }
            answered += 1;
            assert!(!what.starts_with("cut"), "{id}, {what}: answered {located}");
            if expected == "distal" {
                assert_ne!(located, "proximal", "{id}, {what}");
                if let (Some(k2), Some(sigma)) = (a.k2, a.sigma) {
                    let k2_true = k2_true.unwrap();
                    assert!(
                        (k2 - k2_true).abs() <= 3.0 * sigma,
                        "{id}, {what}: k̂2 {k2} m against {k2_true} m (σ {sigma} m)"
                    );
                }
            } else {
                assert_ne!(
                    located, "distal",
                    "{id} ({expected}), {what}: k̂2 {:?} m",
                    a.k2
                );
            }
        }
    }
    println!("damaged samples: {answered} answered within 3σ, {refused} refused");
    // Most damage leaves a readable grasp: refusing everything would pass the checks above.
    assert!(answered >= 150, "answered {answered}");
}
