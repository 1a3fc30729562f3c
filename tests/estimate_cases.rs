//! The estimate requests `cargo xtask bench --check` runs the firmware's estimate entries on
//! (`crates/pts/benches/thumb/requests/*.req`): requests the real controller built closed
//! loop against the plant, with the host's results of the same entries (the bench requires
//! the target to reproduce them bit for bit) and the f64 reference. Besides the default
//! (seated) controller's, the `*_unseated` cases are shaped like a recording no seating
//! controller made: the step a 4 N·m/s ramp from T_a,c at the detection, the whole loading
//! path in the request.
//!
//! Checked here on every committed case: the firmware's two-point estimate
//! (`grasp::two_point_fw`, Q32.32 on the free-motion table) against the two-point method on
//! the f64 model's Newton solves with the f64 contact point (within 1e-4·l2, same
//! classification), the firmware's path fit (`grasp::path_fit_fw`) against the generic path
//! fit in f64 (within half its σ), and the host lines in the file against the entries run now.
//!
//! Regenerate the files (after a controller change): `REQUEST_CASES_DUMP=1 cargo test
//! --release --test estimate_cases -- --nocapture`.

mod common;

use std::fmt::Write as _;
use std::path::PathBuf;

use grasp::estimate::{contact_point, contact_point_with, path_fit_q_at};
use grasp::{EstimateRequest, EstimateResult, Estimator, Located, Sample};
use pts::fixed::Fx32;
use pts::{Model, Real};

use common::{config, run, unseated, L2};

/// The scenes of the committed cases (the plant's Table 2 case first), at ΔT_a = 0.8 N·m,
/// the firmware's default step.
const SCENES: &[&str] = &[
    "table2",
    "table2_ideal",
    "vertex_k2_30",
    "vertex_k2_70",
    "cyl10_k2_20",
    "cyl30_k2_40",
    "proximal_vertex_k1_50",
];

/// The scenes of the unseated cases (`<scene>_unseated.req`), at ΔT_a = 0.8 N·m.
const UNSEATED_SCENES: &[&str] = &["table2", "vertex_k2_30", "cyl10_k2_20", "cyl30_k2_40"];

fn cases_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("crates/pts/benches/thumb/requests")
}

fn sample_line(key: &str, s: &Sample) -> String {
    format!(
        "{key} {} {} {} {}\n",
        s.tick, s.theta_a_urad, s.torque_unm, s.torque_ref_unm
    )
}

/// One result as the bench compares it: status, located, k2, K̂c, θa,c, T_a,c.
fn result_line(key: &str, r: &Result<EstimateResult, grasp::EstimateError>) -> String {
    match r {
        Ok(r) => format!(
            "{key} ok {} {} {} {} {}\n",
            located_code(r.located),
            r.k2_um.unwrap_or(i32::MIN),
            r.kc_hat_unm_per_rad,
            r.theta_a_c_urad,
            r.ta_c_unm
        ),
        Err(e) => format!("{key} err {}\n", e.kind()),
    }
}

fn located_code(l: Located) -> i32 {
    match l {
        Located::Proximal => 0,
        Located::Distal => 1,
        Located::ProximalOrNearO2 => 2,
    }
}

/// The request's lines (what the bench loads).
fn request_text(req: &EstimateRequest) -> String {
    let mut s = format!(
        "params {} {} {} {} {}\n",
        req.sample_ticks,
        req.path_stride,
        req.delta_ta_cmd_unm,
        req.detect_k_unm_per_rad,
        req.dt_ns
    );
    for (k, v) in [
        ("contact", &req.contact),
        ("seat", &req.seat),
        ("seat2", &req.seat2),
        ("end", &req.end),
    ] {
        s += &sample_line(k, v);
    }
    for p in &req.pre {
        s += &sample_line("pre", p);
    }
    for p in &req.path {
        s += &sample_line("path", p);
    }
    s
}

fn parse(text: &str) -> (EstimateRequest, Vec<String>) {
    let mut req = EstimateRequest::EMPTY;
    let mut results = Vec::new();
    for line in text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
    {
        let mut w = line.split_whitespace();
        let key = w.next().unwrap();
        let nums = || -> Vec<i64> {
            line.split_whitespace()
                .skip(1)
                .map(|v| v.parse().expect("number"))
                .collect()
        };
        let sample = || {
            let v = nums();
            Sample {
                tick: v[0] as u32,
                theta_a_urad: v[1] as i32,
                torque_unm: v[2] as i32,
                torque_ref_unm: v[3] as i32,
            }
        };
        match key {
            "params" => {
                let v = nums();
                req.sample_ticks = v[0] as u32;
                req.path_stride = v[1] as u32;
                req.delta_ta_cmd_unm = v[2] as i32;
                req.detect_k_unm_per_rad = v[3] as i32;
                req.dt_ns = v[4] as u32;
            }
            "contact" => req.contact = sample(),
            "seat" => req.seat = sample(),
            "seat2" => req.seat2 = sample(),
            "end" => req.end = sample(),
            "pre" => req.pre.push(sample()).expect("pre fits"),
            "path" => req.path.push(sample()).expect("path fits"),
            _ => results.push(line.to_string() + "\n"),
        }
    }
    (req, results)
}

/// The firmware's results on the host for a request: two-point and path fit.
fn host_results(req: &EstimateRequest) -> String {
    let f = pts::Finger::PAPER;
    let tp = grasp::two_point_table(&f).expect("two-point table");
    let pt = grasp::path_table(&f, &grasp::DriveConfig::DEFAULT, req.dt_ns).expect("path table");
    result_line("host_two_point", &grasp::two_point_fw(&tp, req))
        + &result_line("host_path_fit", &grasp::path_fit_fw(&pt, req))
}

#[test]
fn dump_cases_when_asked() {
    if std::env::var_os("REQUEST_CASES_DUMP").is_none() {
        return;
    }
    std::fs::create_dir_all(cases_dir()).unwrap();
    // (scenes, file suffix, the controller in the comment line, its configuration)
    type Variant = (
        &'static [&'static str],
        &'static str,
        &'static str,
        fn(&plant::Scene, f64) -> grasp::ControllerConfig,
    );
    let variants: [Variant; 2] = [
        (SCENES, "", "", config),
        (
            UNSEATED_SCENES,
            "_unseated",
            "unseated (4 N·m/s ramp) ",
            unseated,
        ),
    ];
    for (scenes, suffix, label, cfg) in variants {
        for name in scenes {
            dump_case(name, suffix, label, cfg);
        }
    }
}

/// Runs one scene closed loop at ΔT_a = 0.8 N·m and writes its request case.
fn dump_case(
    name: &str,
    suffix: &str,
    label: &str,
    cfg: fn(&plant::Scene, f64) -> grasp::ControllerConfig,
) {
    let s = plant::scenes::by_name(name).expect("scene");
    let o = run(&s, cfg(&s, 0.8), 30.0, 0.0, |_, _, _| {});
    let req = o.request.expect("the controller built a request");
    let mut text = String::new();
    let truth = o
        .first_contact
        .map_or(-1, |(_, k)| (k * 1e6).round() as i64);
    writeln!(
        text,
        "# scene {name}, ΔT_a 0.8 N·m, the paper's finger: the request the {label}controller \
             built closed loop (tests/estimate_cases.rs); first contact at {truth} µm"
    )
    .unwrap();
    text += &request_text(&req);
    text += &host_results(&req);
    let path = cases_dir().join(format!("{name}{suffix}.req"));
    std::fs::write(&path, text).unwrap();
    println!("wrote {}", path.display());
}

fn committed() -> Vec<(String, EstimateRequest, Vec<String>)> {
    let mut v: Vec<_> = std::fs::read_dir(cases_dir())
        .expect("committed request cases")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "req"))
        .map(|p| {
            let (req, res) = parse(&std::fs::read_to_string(&p).unwrap());
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                req,
                res,
            )
        })
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

#[test]
fn the_committed_cases_include_table2_and_parse_back_to_themselves() {
    let cases = committed();
    assert!(cases.len() >= 5, "only {} cases", cases.len());
    assert!(cases.iter().any(|c| c.0 == "table2.req"));
    for (name, req, _) in &cases {
        let (again, _) = parse(&request_text(req));
        assert_eq!(&again, req, "{name}");
        assert!(req.pre.len() >= 12 && !req.path.is_empty(), "{name}");
    }
}

/// `REQUEST_CASES_RESULTS=1`: rewrites the host lines of every committed case with what the
/// firmware entries compute now, keeping its request (a change of the estimator, not of the
/// controller that built the requests; `REQUEST_CASES_DUMP` rebuilds both).
#[test]
fn the_host_lines_are_what_the_firmware_entries_compute_now() {
    let rewrite = std::env::var_os("REQUEST_CASES_RESULTS").is_some();
    for (name, req, results) in committed() {
        let want: String = results.concat();
        let now = host_results(&req);
        if rewrite && now != want {
            let path = cases_dir().join(&name);
            let text = std::fs::read_to_string(&path).unwrap();
            let kept: String = text
                .lines()
                .filter(|l| !l.starts_with("host_"))
                .flat_map(|l| [l, "\n"])
                .collect();
            std::fs::write(&path, kept + &now).unwrap();
            println!("rewrote the host lines of {name}");
            continue;
        }
        assert_eq!(
            now, want,
            "{name}: regenerate the cases' host lines (REQUEST_CASES_RESULTS=1)"
        );
    }
}

/// A firmware two-point result against the f64 model's on one case: same classification,
/// k2 within 1e-4·l2, the same contact point (θa,c within 2 µrad, T_a,c within 20 µN·m), or
/// the same refusal. True when it located a distal contact.
fn two_point_agrees(
    name: &str,
    fw: Result<EstimateResult, grasp::EstimateError>,
    reference: Result<EstimateResult, pts::PtsError>,
) -> bool {
    match (fw, reference) {
        (Ok(a), Ok(b)) => {
            assert_eq!(a.located, b.located, "{name}");
            assert!(
                (a.theta_a_c_urad - b.theta_a_c_urad).abs() <= 2,
                "{name}: θa,c {} vs {} µrad",
                a.theta_a_c_urad,
                b.theta_a_c_urad
            );
            assert!(
                (a.ta_c_unm - b.ta_c_unm).abs() <= 20,
                "{name}: T_a,c {} vs {} µN·m",
                a.ta_c_unm,
                b.ta_c_unm
            );
            match (a.k2_um, b.k2_um) {
                (Some(x), Some(y)) => {
                    let err = f64::from(x - y).abs() * 1e-6;
                    assert!(err <= 1e-4 * L2, "{name}: k2 {x} µm vs f64 {y} µm");
                    true
                }
                (None, None) => false,
                other => panic!("{name}: {other:?}"),
            }
        }
        (Err(a), Err(b)) => {
            assert_eq!(a, grasp::EstimateError::Model(b), "{name}");
            false
        }
        other => panic!("{name}: {other:?}"),
    }
}

#[test]
fn the_firmware_two_point_estimate_matches_the_f64_model() {
    let m64 = Model::<f64>::paper().unwrap();
    let tp = grasp::two_point_table(&pts::Finger::PAPER).unwrap();
    let mut distal = 0;
    for (name, req, _) in committed() {
        let fw = grasp::two_point_fw(&tp, &req);
        let reference = grasp::estimate::two_point(&m64, &req);
        distal += usize::from(two_point_agrees(&name, fw, reference));
    }
    assert!(distal >= 4, "only {distal} distal cases");
}

/// The two-point estimate a path-fit firmware reports (beside the fit, or when a grasp asks
/// for the two-point method): on the path fit's table, against the f64 model's.
#[test]
fn the_two_point_estimate_on_the_path_table_matches_the_f64_model() {
    let m64 = Model::<f64>::paper().unwrap();
    let mut distal = 0;
    for (name, req, _) in committed() {
        let table = grasp::path_table(&pts::Finger::PAPER, &grasp::DriveConfig::DEFAULT, req.dt_ns)
            .unwrap();
        let fw = grasp::estimate::two_point_q(&table, &req).map_err(grasp::EstimateError::Model);
        let reference = grasp::estimate::two_point(&m64, &req);
        distal += usize::from(two_point_agrees(&name, fw, reference));
    }
    assert!(distal >= 4, "only {distal} distal cases");
}

#[test]
fn the_firmware_path_fit_lands_within_half_sigma_of_the_f64_fit() {
    let m64 = Model::<f64>::paper().unwrap();
    let mut located = 0;
    for (name, mut req, _) in committed() {
        req.estimator = Estimator::PathFit;
        let table = grasp::path_table(&pts::Finger::PAPER, &grasp::DriveConfig::DEFAULT, req.dt_ns)
            .unwrap();
        let fw = grasp::path_fit_fw(&table, &req);
        let reference = grasp::estimate::path_fit(&m64, &grasp::DriveConfig::DEFAULT, &req);
        let (th, tc) = contact_point_with(&req, |th: Fx32| table.free_torque(th).ok())
            .unwrap_or_else(|| contact_point(&req));
        let sigma = path_fit_q_at(&table, &req, th.to_f64(), tc.to_f64())
            .ok()
            .and_then(|(_, s)| s);
        match (fw, reference) {
            (Ok(a), Ok(b)) => {
                assert_eq!(a.located, b.located, "{name}");
                if let (Some(x), Some(y), Some(s)) = (a.k2_um, b.k2_um, sigma) {
                    located += 1;
                    let err = f64::from(x - y).abs() * 1e-6;
                    assert!(err <= 0.5 * s, "{name}: k2 {x} µm vs f64 {y} µm, σ {s}");
                }
            }
            (Err(_), Err(_)) => {}
            other => panic!("{name}: {other:?}"),
        }
    }
    assert!(located >= 3, "only {located} located");
}
