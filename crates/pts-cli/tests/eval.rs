//! `pts eval` acceptance: answers against an independent reference written here from MODEL.md
//! (the paper's tan(γ/2) quadratic, derivatives by second-order Taylor jets, free motion and
//! inversion by bisection), every error kind, and malformed lines that must not stop the stream.

use serde_json::Value;
use std::io::Write;
use std::process::{Command, Stdio};

// ---------------------------------------------------------------- independent reference

/// A second-order jet: value, first and second derivative with respect to one variable.
#[derive(Clone, Copy, Debug)]
struct J(f64, f64, f64);

impl J {
    fn c(x: f64) -> J {
        J(x, 0.0, 0.0)
    }
    fn var(x: f64) -> J {
        J(x, 1.0, 0.0)
    }
    /// f∘self given f, f′, f″ at self.0.
    fn chain(self, f: f64, d1: f64, d2: f64) -> J {
        J(f, d1 * self.1, d2 * self.1 * self.1 + d1 * self.2)
    }
    fn sin(self) -> J {
        let (s, c) = self.0.sin_cos();
        self.chain(s, c, -s)
    }
    fn cos(self) -> J {
        let (s, c) = self.0.sin_cos();
        self.chain(c, -s, -c)
    }
    fn sqrt(self) -> J {
        let r = self.0.sqrt();
        self.chain(r, 0.5 / r, -0.25 / (r * self.0))
    }
    fn atan(self) -> J {
        let x = self.0;
        let d = 1.0 / (1.0 + x * x);
        self.chain(x.atan(), d, -2.0 * x * d * d)
    }
    fn recip(self) -> J {
        let x = self.0;
        self.chain(1.0 / x, -1.0 / (x * x), 2.0 / (x * x * x))
    }
}
impl std::ops::Add for J {
    type Output = J;
    fn add(self, o: J) -> J {
        J(self.0 + o.0, self.1 + o.1, self.2 + o.2)
    }
}
impl std::ops::Sub for J {
    type Output = J;
    fn sub(self, o: J) -> J {
        J(self.0 - o.0, self.1 - o.1, self.2 - o.2)
    }
}
impl std::ops::Mul for J {
    type Output = J;
    fn mul(self, o: J) -> J {
        J(
            self.0 * o.0,
            self.1 * o.0 + self.0 * o.1,
            self.2 * o.0 + 2.0 * self.1 * o.1 + self.0 * o.2,
        )
    }
}
impl std::ops::Div for J {
    type Output = J;
    fn div(self, o: J) -> J {
        let r = o.recip();
        J(
            self.0 * r.0,
            self.1 * r.0 + self.0 * r.1,
            self.2 * r.0 + 2.0 * self.1 * r.1 + self.0 * r.2,
        )
    }
}

/// Paper Table 1 with the springs of MODEL.md.
#[derive(Clone, Copy)]
struct F {
    l1: f64,
    l2: f64,
    a: f64,
    b: f64,
    c: f64,
    phi2: f64,
    t01: f64,
    t02: f64,
    k1: f64,
    k2: f64,
}
const PAPER: F = F {
    l1: 0.100,
    l2: 0.075,
    a: 0.071,
    b: 0.108,
    c: 0.044,
    phi2: std::f64::consts::FRAC_PI_2,
    t01: std::f64::consts::FRAC_PI_4,
    t02: 0.0,
    k1: 0.6895,
    k2: 1.0274,
};

impl F {
    /// γ(θ2) as a jet in θ2 from Eqs. 15–17: T = (−E + √(E² − 4DF))/(2D), γ = 2 atan T.
    fn gamma(&self, theta2: f64) -> J {
        let z1 = (self.l1 * self.l1 + self.c * self.c + self.a * self.a - self.b * self.b)
            / (2.0 * self.a * self.l1);
        let z2 = self.c / self.l1;
        let z3 = self.c / self.a;
        let lam = J::var(theta2) + J::c(std::f64::consts::PI - self.phi2);
        let cl = lam.cos();
        let d = J::c(z1 + z2) - J::c(1.0 + z3) * cl;
        let e = J::c(2.0) * lam.sin();
        let f = J::c(z1 - z2) + J::c(1.0 - z3) * cl;
        let t = (J::c(0.0) - e + (e * e - J::c(4.0) * d * f).sqrt()) / (J::c(2.0) * d);
        J::c(2.0) * t.atan()
    }
    /// (γ, θa, x2, dx2/dθ2).
    fn closure(&self, theta1: f64, theta2: f64) -> (f64, f64, f64, f64) {
        let g = self.gamma(theta2);
        // θa = θ1 + θ2 − φ2 − γ; x2 = ∂θa/∂θ2 = 1 − γ′; dx2 = −γ″.
        (g.0, theta1 + theta2 - self.phi2 - g.0, 1.0 - g.1, -g.2)
    }
    fn k2p(&self, theta2: f64, ta: f64) -> f64 {
        self.k2 - ta * self.closure(0.0, theta2).3
    }
    fn kc_prox(&self, theta2: f64, ta: f64) -> f64 {
        let x2 = self.closure(0.0, theta2).2;
        self.k2p(theta2, ta) / (x2 * x2)
    }
    fn kc_dist(&self, theta2: f64, ta: f64, k: f64) -> f64 {
        let x2 = self.closure(0.0, theta2).2;
        let s = k / (self.l1 * theta2.cos() + k);
        (self.k1 * s * s + self.k2p(theta2, ta)) / ((s - x2) * (s - x2))
    }
    fn kc_free(&self, theta2: f64, ta: f64) -> f64 {
        let x2 = self.closure(0.0, theta2).2;
        1.0 / (1.0 / self.k1 + x2 * x2 / self.k2p(theta2, ta))
    }
    /// Free motion at torque ta: (θ1, θ2, θa).
    fn free(&self, ta: f64) -> (f64, f64, f64) {
        let theta1 = self.t01 + ta / self.k1;
        let g = |t2: f64| self.k2 * (t2 - self.t02) - ta * self.closure(theta1, t2).2;
        let t2 = bisect(g, -0.5, 1.5);
        (theta1, t2, self.closure(theta1, t2).1)
    }
    /// Free motion at actuator angle θa: (θ1, θ2, T_a).
    fn free_at(&self, theta_a: f64) -> (f64, f64, f64) {
        let th1 = |t2: f64| theta_a - t2 + self.phi2 + self.gamma(t2).0;
        let g = |t2: f64| {
            let ta = self.k1 * (th1(t2) - self.t01);
            self.k2 * (t2 - self.t02) - ta * self.closure(0.0, t2).2
        };
        let t2 = bisect(g, -0.5, 1.5);
        (th1(t2), t2, self.k1 * (th1(t2) - self.t01))
    }
    /// k2 with kc_dist(k2) = kc, by bisection on (0, l2].
    fn invert(&self, theta2: f64, ta: f64, kc: f64) -> f64 {
        bisect(|k| self.kc_dist(theta2, ta, k) - kc, 1e-9, self.l2)
    }
}

/// Root of an increasing-or-decreasing function on [lo, hi], to the last bit.
fn bisect(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let flo = f(lo);
    assert!(flo * f(hi) <= 0.0, "no sign change on [{lo}, {hi}]");
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid == lo || mid == hi {
            break;
        }
        if (f(mid) > 0.0) == (flo > 0.0) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

// ---------------------------------------------------------------- running the tool

fn run_eval(args: &[&str], lines: &[String]) -> Vec<Value> {
    let mut child = Command::new(env!("CARGO_BIN_EXE_pts"))
        .arg("eval")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn pts");
    let mut input = lines.join("\n");
    input.push('\n');
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "exit {:?}", out.status);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(!text.contains("NaN") && !text.contains("inf"), "{text}");
    let answers: Vec<Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{l}: {e}")))
        .collect();
    assert_eq!(answers.len(), lines.len(), "one answer per line:\n{text}");
    answers
}

fn f(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("no number \"{key}\" in {v}"))
}

fn assert_rel(got: f64, want: f64, rel: f64, what: &str) {
    let err = (got - want).abs();
    assert!(
        err <= rel * want.abs().max(1e-3),
        "{what}: got {got}, want {want} (rel err {:.3e})",
        err / want.abs().max(1e-300)
    );
}

const REL: f64 = 1e-9;

// ---------------------------------------------------------------- f64 answers

#[test]
fn closure_matches_reference() {
    let cases = [
        (std::f64::consts::FRAC_PI_4, 0.0),
        (1.2797, 0.209196),
        (1.0, 0.5),
        (0.9, -0.3),
        (1.5, 1.2),
    ];
    let lines: Vec<String> = cases
        .iter()
        .map(|(t1, t2)| format!(r#"{{"op":"closure","theta1":{t1},"theta2":{t2}}}"#))
        .collect();
    let out = run_eval(&[], &lines);
    for ((t1, t2), a) in cases.iter().zip(&out) {
        assert_eq!(a["ok"], true, "{a}");
        let (g, ta, x2, dx2) = PAPER.closure(*t1, *t2);
        assert_rel(f(a, "gamma"), g, REL, "gamma");
        assert_rel(f(a, "theta_a"), ta, REL, "theta_a");
        assert_rel(f(a, "x2"), x2, REL, "x2");
        assert_rel(f(a, "dx2"), dx2, REL, "dx2");
    }
    // MODEL.md's rest numbers.
    assert!((f(&out[0], "theta_a") - -0.8503608).abs() < 1e-6);
    assert!((f(&out[0], "x2") - 0.6315740).abs() < 1e-7);
    assert!((f(&out[0], "dx2") - 0.0328355).abs() < 1e-7);
}

#[test]
fn kc_matches_closed_forms_on_both_phalanges() {
    let mut lines = vec![];
    let mut want = vec![];
    for &(t2, ta) in &[(0.0, 0.0), (0.209196, 0.340821), (0.6, 0.8)] {
        lines.push(format!(
            r#"{{"op":"kc","theta1":1.0,"theta2":{t2},"ta":{ta},"phalanx":1,"k":0.05}}"#
        ));
        want.push(PAPER.kc_prox(t2, ta));
        for k in [0.005, 0.02927, 0.05, 0.075] {
            lines.push(format!(
                r#"{{"op":"kc","theta1":1.0,"theta2":{t2},"ta":{ta},"phalanx":2,"k":{k}}}"#
            ));
            want.push(PAPER.kc_dist(t2, ta, k));
        }
    }
    let out = run_eval(&[], &lines);
    for ((a, w), l) in out.iter().zip(&want).zip(&lines) {
        assert_rel(f(a, "kc"), *w, REL, l);
    }
    // Table 2: K_c = 6.7249 at k2 = 2.927 cm; proximal 2.6179, tip 30.2825.
    assert!((f(&out[5], "kc") - 2.6179).abs() < 5e-5, "{}", out[5]);
    assert!((f(&out[7], "kc") - 6.7249).abs() < 5e-5, "{}", out[7]);
    assert!((f(&out[9], "kc") - 30.2825).abs() < 5e-5, "{}", out[9]);
}

#[test]
fn free_matches_bisection() {
    let tas = [0.0, 0.1, 0.340821, 0.8];
    let lines: Vec<String> = tas
        .iter()
        .map(|ta| format!(r#"{{"op":"free","ta":{ta}}}"#))
        .collect();
    let out = run_eval(&[], &lines);
    for (ta, a) in tas.iter().zip(&out) {
        let (t1, t2, tha) = PAPER.free(*ta);
        assert_rel(f(a, "theta1"), t1, REL, "theta1");
        // θ2 = 0 at rest: compare absolutely there.
        assert!(
            (f(a, "theta2") - t2).abs() <= REL * t2.abs().max(1e-3),
            "{a}"
        );
        assert_rel(f(a, "theta_a"), tha, REL, "theta_a");
        assert_rel(f(a, "kc"), PAPER.kc_free(t2, *ta), REL, "kc");
    }
    assert!((f(&out[0], "kc") - 0.54390).abs() < 1e-5);
    assert!((f(&out[2], "theta2") - 0.209196).abs() < 1e-6);
}

#[test]
fn invert_classifies_and_locates() {
    let (t1, t2, ta) = (1.2797, 0.209196, 0.340821);
    let free = PAPER.kc_free(t2, ta);
    let prox = PAPER.kc_prox(t2, ta);
    let tip = PAPER.kc_dist(t2, ta, PAPER.l2);
    let kcs = [
        free,
        0.5 * (free + prox),
        0.99 * prox,
        6.7249,
        9.965,
        0.999 * tip,
    ];
    let lines: Vec<String> = kcs
        .iter()
        .map(|kc| format!(r#"{{"op":"invert","theta1":{t1},"theta2":{t2},"ta":{ta},"kc":{kc}}}"#))
        .collect();
    let out = run_eval(&[], &lines);
    assert_eq!(out[0]["phalanx"], "none", "{}", out[0]);
    assert_eq!(out[0]["k2"], Value::Null);
    // The midpoint of free and proximal is above their geometric mean: proximal.
    assert_eq!(out[1]["phalanx"], "proximal", "{}", out[1]);
    assert_eq!(out[2]["phalanx"], "proximal");
    assert_eq!(out[2]["k2"], Value::Null);
    for (kc, a) in kcs.iter().zip(&out).skip(3) {
        assert_eq!(a["phalanx"], "distal", "{a}");
        assert_rel(f(a, "k2"), PAPER.invert(t2, ta, *kc), REL, "k2");
    }
    // MODEL.md: K̂c = 9.9650 at the contact configuration → 4.1529 cm.
    assert!((f(&out[4], "k2") - 0.041529).abs() < 2e-6, "{}", out[4]);
    assert!((f(&out[3], "k2") - 0.02927).abs() < 2e-6, "{}", out[3]);
}

#[test]
fn estimate_matches_table2() {
    let (t1c, t2c, thac) = PAPER.free(0.6895 * (1.2797 - std::f64::consts::FRAC_PI_4));
    let ta_c = 0.6895 * (1.2797 - std::f64::consts::FRAC_PI_4);
    let (tha, ta) = (thac + 0.0802814, ta_c + 0.8);
    let line = format!(
        r#"{{"op":"estimate","theta_a_c":{thac},"ta_c":{ta_c},"theta_a":{tha},"ta":{ta}}}"#
    );
    let out = run_eval(&[], &[line]);
    let a = &out[0];
    let kc_hat = 0.8 / (tha - thac);
    assert_rel(f(a, "kc_hat"), kc_hat, REL, "kc_hat");
    let (r1, r2, _) = PAPER.free_at(thac);
    assert_rel(f(a, "theta1_c"), r1, REL, "theta1_c");
    assert_rel(f(a, "theta2_c"), r2, REL, "theta2_c");
    assert_rel(f(a, "theta1_c"), t1c, 1e-9, "theta1_c vs torque solve");
    assert_rel(f(a, "theta2_c"), t2c, 1e-9, "theta2_c vs torque solve");
    assert_eq!(a["phalanx"], "distal");
    // Inverted with the torque measured at contact (the G term).
    assert_rel(f(a, "k2"), PAPER.invert(r2, ta_c, kc_hat), REL, "k2");
    assert!((f(a, "kc_hat") - 9.9650).abs() < 5e-4);
    assert!((f(a, "k2") - 0.041529).abs() < 2e-6, "{a}");
}

#[test]
fn spring_overrides_apply_per_request() {
    let soft = F {
        k1: 0.4,
        k2: 2.0,
        ..PAPER
    };
    let lines = vec![
        r#"{"op":"free","ta":0.3,"K1":0.4,"K2":2.0}"#.to_string(),
        r#"{"op":"free","ta":0.3}"#.to_string(),
        r#"{"op":"kc","theta1":1,"theta2":0.2,"ta":0.3,"phalanx":2,"k":0.03,"K1":0.4,"K2":2.0}"#
            .to_string(),
        r#"{"op":"free","ta":0.3,"K2":-1}"#.to_string(),
    ];
    let out = run_eval(&[], &lines);
    let (t1, t2, _) = soft.free(0.3);
    assert_rel(f(&out[0], "theta1"), t1, REL, "theta1 soft");
    assert_rel(f(&out[0], "theta2"), t2, REL, "theta2 soft");
    assert_rel(f(&out[0], "kc"), soft.kc_free(t2, 0.3), REL, "kc soft");
    // The override does not leak into the next line.
    assert_rel(f(&out[1], "theta1"), PAPER.free(0.3).0, REL, "theta1 paper");
    assert_rel(
        f(&out[2], "kc"),
        soft.kc_dist(0.2, 0.3, 0.03),
        REL,
        "kc soft",
    );
    assert_eq!(out[3]["error"], "invalid_finger", "{}", out[3]);
}

#[test]
fn finger_file_is_used() {
    let dir = std::env::temp_dir().join(format!("pts-eval-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("soft.toml");
    std::fs::write(
        &path,
        "[springs]\nk1_nm_per_rad = 0.4\nk2_nm_per_rad = 2.0\n",
    )
    .unwrap();
    let out = run_eval(
        &["--finger", path.to_str().unwrap()],
        &[r#"{"op":"free","ta":0.3}"#.to_string()],
    );
    let soft = F {
        k1: 0.4,
        k2: 2.0,
        ..PAPER
    };
    assert_rel(f(&out[0], "theta2"), soft.free(0.3).1, REL, "theta2");
    // A bad finger file is a clear error at start, naming the key.
    std::fs::write(&path, "[springs]\nk2_nm_per_rad = -2.0\n").unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_pts"))
        .args(["eval", "--finger", path.to_str().unwrap()])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("springs.k2_nm_per_rad"), "{err}");
}

// ---------------------------------------------------------------- errors

fn kind_of(v: &Value) -> &str {
    assert_eq!(v["ok"], false, "{v}");
    assert!(v["message"].as_str().is_some_and(|m| !m.is_empty()), "{v}");
    v["error"].as_str().unwrap()
}

#[test]
fn every_model_error_kind_is_reported_per_line() {
    let cases: &[(&str, &str)] = &[
        (r#"{"op":"closure","theta1":1,"theta2":2.3557}"#, "toggle"),
        (
            r#"{"op":"closure","theta1":100,"theta2":0}"#,
            "out_of_range",
        ),
        (r#"{"op":"free","ta":5000}"#, "out_of_range"),
        (
            r#"{"op":"invert","theta1":1.2797,"theta2":0.209196,"ta":0.340821,"kc":50}"#,
            "beyond_tip",
        ),
        (
            r#"{"op":"invert","theta1":1.2797,"theta2":0.209196,"ta":0.340821,"kc":0.3}"#,
            "stiffness_below_free",
        ),
        (
            r#"{"op":"invert","theta1":1.6,"theta2":1.0,"ta":0.340821,"kc":5}"#,
            "not_monotone",
        ),
        (
            r#"{"op":"kc","theta1":1,"theta2":0.2,"ta":0.3,"phalanx":2,"k":0.1}"#,
            "contact_outside_phalanx",
        ),
        (
            r#"{"op":"kc","theta1":1,"theta2":0.2,"ta":0.3,"phalanx":1,"k":-0.01}"#,
            "contact_outside_phalanx",
        ),
        (
            r#"{"op":"estimate","theta_a_c":-0.22,"ta_c":0.34,"theta_a":-0.21,"ta":0.34}"#,
            "delta_torque_not_positive",
        ),
        (
            r#"{"op":"estimate","theta_a_c":-0.22,"ta_c":0.34,"theta_a":-0.22,"ta":0.5}"#,
            "delta_theta_too_small",
        ),
        // Δθa of about two encoder steps: one step would move k2 by more than 5 % of l2.
        (
            r#"{"op":"estimate","theta_a_c":-0.223771,"ta_c":0.340821,"theta_a":-0.2237,"ta":0.342}"#,
            "ill_conditioned",
        ),
        (r#"{"op":"free","ta":0.3,"K1":-1}"#, "invalid_finger"),
        (r#"{"op":"free","ta":0.3,"K2":0}"#, "invalid_finger"),
    ];
    let lines: Vec<String> = cases.iter().map(|(l, _)| l.to_string()).collect();
    let out = run_eval(&[], &lines);
    for ((line, kind), a) in cases.iter().zip(&out) {
        assert_eq!(kind_of(a), *kind, "{line} -> {a}");
    }
}

#[test]
fn not_assemblable_with_a_short_coupler() {
    // A short coupler (b = 5 cm) closes at rest (|O1Ob| = 10.9 cm ≤ a + b = 12.1 cm) but not
    // once flexion swings the distal crank out (|O1Ob| → l1 + c = 14.4 cm).
    let dir = std::env::temp_dir().join(format!("pts-eval-na-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("short.toml");
    std::fs::write(&path, "[geometry]\nb_m = 0.05\n").unwrap();
    let lines: Vec<String> = [0.0, 1.0]
        .iter()
        .map(|t2| format!(r#"{{"op":"closure","theta1":1,"theta2":{t2}}}"#))
        .collect();
    let out = run_eval(&["--finger", path.to_str().unwrap()], &lines);
    assert_eq!(out[0]["ok"], true, "{}", out[0]);
    assert_eq!(kind_of(&out[1]), "not_assemblable", "{}", out[1]);
}

#[test]
fn malformed_lines_are_bad_requests_and_the_stream_goes_on() {
    let good = r#"{"op":"free","ta":0}"#;
    let bad = [
        "not json",
        "",
        "[1,2]",
        "42",
        r#"{"ta":0}"#,
        r#"{"op":7,"ta":0}"#,
        r#"{"op":"fly","ta":0}"#,
        r#"{"op":"free"}"#,
        r#"{"op":"free","ta":"0.3"}"#,
        r#"{"op":"free","ta":null}"#,
        r#"{"op":"free","ta":[0.3]}"#,
        r#"{"op":"free","ta":NaN}"#,
        r#"{"op":"free","ta":1e999}"#,
        r#"{"op":"free","ta":-Infinity}"#,
        r#"{"op":"free","ta":0,"k1":1}"#,
        r#"{"op":"free","ta":0,"K1":"stiff"}"#,
        r#"{"op":"kc","theta1":1,"theta2":0.2,"ta":0.3,"phalanx":3,"k":0.03}"#,
        r#"{"op":"kc","theta1":1,"theta2":0.2,"ta":0.3,"phalanx":"distal","k":0.03}"#,
        r#"{"op":"kc","theta1":1,"theta2":0.2,"ta":0.3,"phalanx":1.5,"k":0.03}"#,
        r#"{"op":"free","ta":0.1"#,
        "\u{feff}garbage \u{1F600}",
    ];
    let mut lines = vec![];
    for b in bad {
        lines.push(b.to_string());
        lines.push(good.to_string());
    }
    let out = run_eval(&[], &lines);
    for (i, b) in bad.iter().enumerate() {
        assert_eq!(
            kind_of(&out[2 * i]),
            "bad_request",
            "{b:?} -> {}",
            out[2 * i]
        );
        assert_eq!(out[2 * i + 1]["ok"], true, "after {b:?}");
    }
}

#[test]
fn invalid_utf8_and_crlf_lines_do_not_stop_the_stream() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_pts"))
        .arg("eval")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let input: &[u8] = b"{\"op\":\"free\",\"ta\":0}\r\n\xff\xfe{\"op\"\n{\"op\":\"free\",\"ta\":0}";
    child.stdin.take().unwrap().write_all(input).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    let answers: Vec<Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(answers.len(), 3, "{text}");
    assert_eq!(answers[0]["ok"], true);
    assert_eq!(kind_of(&answers[1]), "bad_request");
    // The last line has no newline: still answered.
    assert_eq!(answers[2]["ok"], true);
}

#[test]
fn id_is_echoed() {
    let out = run_eval(
        &[],
        &[
            r#"{"id":"a1","op":"free","ta":0}"#.to_string(),
            r#"{"id":2,"op":"free"}"#.to_string(),
        ],
    );
    assert_eq!(out[0]["id"], "a1");
    assert_eq!(out[1]["id"], 2);
    assert_eq!(out[1]["error"], "bad_request");
}

// ---------------------------------------------------------------- path (the plant)

#[test]
fn path_matches_table2_and_the_free_motion_at_contact() {
    let out = run_eval(
        &[],
        &[
            r#"{"op":"path","theta1_c":1.2797,"phalanx":2,"k_c":0.02927,"radius":0.05,"dta":0.8}"#
                .to_string(),
        ],
    );
    let a = &out[0];
    assert_eq!(a["ok"], true, "{a}");
    // The contact instant is free motion at θ1,c: T_a,c = K1(θ1,c − θ01), θa,c from the
    // independent tan(γ/2) reference.
    let ta_c = PAPER.k1 * (1.2797 - PAPER.t01);
    assert_rel(f(a, "ta_c"), ta_c, REL, "ta_c");
    let (_, t2c, _) = PAPER.free(ta_c);
    let thac = PAPER.closure(1.2797, t2c).1;
    assert_rel(f(a, "theta_a_c"), thac, 1e-8, "theta_a_c");
    assert_rel(
        f(a, "dtheta_a"),
        f(a, "theta_a") - f(a, "theta_a_c"),
        1e-12,
        "dtheta_a",
    );
    // MODEL.md: Δθa = 0.08028 rad (paper 0.08), k2 after the step 0.039414 m (paper 3.941 cm).
    assert!((f(a, "dtheta_a") - 0.08028).abs() < 1e-5, "{a}");
    assert!((f(a, "k") - 0.039414).abs() < 1e-6, "{a}");
}

#[test]
fn path_errors() {
    let cases = [
        (
            r#"{"op":"path","theta1_c":1.2797,"phalanx":2,"k_c":0.01,"radius":0.0975,"dta":0.8}"#,
            "second_contact",
        ),
        (
            r#"{"op":"path","theta1_c":1.2797,"phalanx":2,"k_c":0.074,"radius":0,"dta":0.8}"#,
            "beyond_tip",
        ),
        (
            r#"{"op":"path","theta1_c":1.2797,"phalanx":2,"k_c":0.03,"radius":0,"dta":-0.5}"#,
            "loss_of_contact",
        ),
        (
            r#"{"op":"path","theta1_c":1.2797,"phalanx":2,"k_c":0.09,"radius":0,"dta":0.3}"#,
            "contact_outside_phalanx",
        ),
        (
            r#"{"op":"path","theta1_c":1.2797,"phalanx":2,"k_c":0.03,"radius":-1,"dta":0.3}"#,
            "bad_request",
        ),
        (
            r#"{"op":"path","theta1_c":1.2797,"phalanx":0,"k_c":0.03,"radius":0,"dta":0.3}"#,
            "bad_request",
        ),
    ];
    let lines: Vec<String> = cases.iter().map(|(l, _)| l.to_string()).collect();
    let out = run_eval(&[], &lines);
    for ((line, kind), a) in cases.iter().zip(&out) {
        assert_eq!(kind_of(a), *kind, "{line} -> {a}");
    }
}

// ---------------------------------------------------------------- fixed point

#[test]
fn fixed_back_end_within_pts_tolerances() {
    // Tolerances of crates/pts/tests/prop_fixed.rs: γ, x2 1e-8 abs, dx2 1e-7 abs, θ 1e-7,
    // K_c proximal/free 1e-6 rel, distal 1e-4 rel, K̂c 1e-4 rel, k2 1e-4·l2.
    let ta_c = PAPER.k1 * (1.2797 - PAPER.t01);
    let (t1c, t2c, thac) = PAPER.free(ta_c);
    let lines = vec![
        format!(r#"{{"op":"closure","theta1":1.2797,"theta2":0.209196}}"#),
        format!(r#"{{"op":"kc","theta1":1,"theta2":0.209196,"ta":0.340821,"phalanx":1,"k":0.05}}"#),
        format!(
            r#"{{"op":"kc","theta1":1,"theta2":0.209196,"ta":0.340821,"phalanx":2,"k":0.02927}}"#
        ),
        format!(r#"{{"op":"free","ta":{ta_c}}}"#),
        format!(r#"{{"op":"invert","theta1":{t1c},"theta2":{t2c},"ta":{ta_c},"kc":9.965}}"#),
        format!(
            r#"{{"op":"estimate","theta_a_c":{thac},"ta_c":{ta_c},"theta_a":{},"ta":{}}}"#,
            thac + 0.0802814,
            ta_c + 0.8
        ),
        r#"{"op":"free","ta":0.3,"K1":1e9}"#.to_string(),
        r#"{"op":"closure","theta1":1,"theta2":2.3557}"#.to_string(),
    ];
    let out = run_eval(&["--numeric", "fixed"], &lines);
    let (g, tha, x2, dx2) = PAPER.closure(1.2797, 0.209196);
    assert!((f(&out[0], "gamma") - g).abs() < 1e-8);
    assert!((f(&out[0], "theta_a") - tha).abs() < 1e-7);
    assert!((f(&out[0], "x2") - x2).abs() < 1e-8);
    assert!((f(&out[0], "dx2") - dx2).abs() < 1e-7);
    assert_rel(
        f(&out[1], "kc"),
        PAPER.kc_prox(0.209196, 0.340821),
        1e-6,
        "prox",
    );
    assert_rel(
        f(&out[2], "kc"),
        PAPER.kc_dist(0.209196, 0.340821, 0.02927),
        1e-4,
        "dist",
    );
    assert!((f(&out[3], "theta2") - t2c).abs() < 1e-7);
    assert!((f(&out[3], "theta_a") - thac).abs() < 1e-7);
    assert_rel(f(&out[3], "kc"), PAPER.kc_free(t2c, ta_c), 1e-6, "free");
    assert_eq!(out[4]["phalanx"], "distal");
    assert!((f(&out[4], "k2") - PAPER.invert(t2c, ta_c, 9.965)).abs() < 1e-4 * PAPER.l2);
    let kc_hat = 0.8 / 0.0802814;
    assert_rel(f(&out[5], "kc_hat"), kc_hat, 1e-4, "kc_hat");
    assert!((f(&out[5], "k2") - PAPER.invert(t2c, ta_c, kc_hat)).abs() < 1e-4 * PAPER.l2);
    // A spring the fixed-point type cannot hold, and the toggle, are errors there too.
    assert_eq!(out[6]["ok"], false, "{}", out[6]);
    assert_eq!(kind_of(&out[7]), "toggle");
}

#[test]
fn finger_command_prints_a_file_that_reads_back() {
    let o = Command::new(env!("CARGO_BIN_EXE_pts"))
        .arg("finger")
        .output()
        .unwrap();
    assert!(o.status.success());
    let text = String::from_utf8(o.stdout).unwrap();
    let f = pts::config::FingerFile::from_toml_str(&text).unwrap();
    assert_eq!(f, pts::config::FingerFile::paper());
}
