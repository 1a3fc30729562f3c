//! The contact point the estimators start from (`grasp::estimate::contact_point_model`)
//! answers its free-motion queries from a quadratic through three model solves instead of
//! one Newton solve per query. Reference: the same search with the f64 model solved exactly
//! at every query (`contact_point_with`), on requests the real controller made closed loop
//! against the plant (ideal and realistic; vertex and cylinders; contacts along the
//! phalanx; small and large ΔT_a).
//!
//! `cargo test --release --test contact_point -- --nocapture` prints the largest deviation.
mod common;

use common::*;
use plant::path::ContactSpec;
use plant::scene::ObjectSpec;
use plant::{Phalanx, Scene};

fn request(realistic: bool, radius: f64, k2_frac: f64, dta: f64) -> Option<grasp::EstimateRequest> {
    let s = Scene {
        name: "contact_point",
        object: ObjectSpec::Touching(ContactSpec {
            theta1_c_rad: 1.2797,
            phalanx: Phalanx::Distal,
            k_c_m: k2_frac * pts::Finger::PAPER.l2,
            radius_m: radius,
        }),
        dt_s: 2e-4,
        ..Scene::DEFAULT
    };
    let s = if realistic { s } else { s.ideal() };
    run(&s, seated(&s, dta), 20.0, 0.0, |_, _, _| {}).request
}

#[test]
fn interpolated_free_curve_matches_exact_solves() {
    let m = pts::Model::<f64>::paper().expect("paper model");
    let exact = |th: f64| m.free_from_theta_a(th).ok().map(|c| c.ta);
    let (mut n, mut worst_th, mut worst_t) = (0, 0.0f64, 0.0f64);
    for realistic in [false, true] {
        for (radius, k2, dta) in [
            (0.0, 0.2, 0.2),
            (0.0, 0.7, 0.8),
            (0.01, 0.5, 0.5),
            (0.05, 0.3, 1.0),
            (0.0975, 0.6, 0.2),
        ] {
            let Some(req) = request(realistic, radius, k2, dta) else {
                continue;
            };
            let reference = grasp::estimate::contact_point_with(&req, exact);
            let fast = grasp::estimate::contact_point_model(&m, &req);
            match (reference, fast) {
                (Some((th_r, t_r)), Some((th_f, t_f))) => {
                    n += 1;
                    worst_th = worst_th.max((th_f - th_r).abs());
                    worst_t = worst_t.max((t_f - t_r).abs());
                }
                (r, f) => panic!(
                    "realistic {realistic} R {radius} k2 {k2} ΔT {dta}: exact {r:?}, fast {f:?}"
                ),
            }
        }
    }
    println!(
        "contact point over {n} requests: |Δθa,c| ≤ {worst_th:.2e} rad, |ΔT_a,c| ≤ {worst_t:.2e} N·m"
    );
    // Far below what the estimate can resolve (the encoder's 1 µrad, the current's µN·m).
    assert!(n >= 8, "too few requests ({n})");
    assert!(worst_th <= 1e-7, "θa,c off by {worst_th:e} rad");
    assert!(worst_t <= 1e-7, "T_a,c off by {worst_t:e} N·m");
}
