//! Independent reference geometry for the tests: the corrected paper closure (MODEL.md:
//! λ = π + θ2 − φ2, γ = atan2(Q,P) − acos(R/√(P²+Q²)), θa = θ1 + θ2 − φ2 − γ), forward
//! kinematics written out here, and central finite differences. Nothing from the plant's solver.
#![allow(dead_code)]

pub const L1: f64 = 0.100;
pub const L2: f64 = 0.075;
pub const A: f64 = 0.071;
pub const B: f64 = 0.108;
pub const C: f64 = 0.044;
pub const PHI2: f64 = std::f64::consts::FRAC_PI_2;
pub const K1: f64 = 0.6895;
pub const K2: f64 = 1.0274;
pub const TH01: f64 = std::f64::consts::FRAC_PI_4;

/// θa(θ1, θ2) by the corrected paper closure.
pub fn theta_a(t1: f64, t2: f64) -> f64 {
    let z1 = (L1 * L1 + C * C + A * A - B * B) / (2.0 * A * L1);
    let z2 = C / L1;
    let z3 = C / A;
    let lam = std::f64::consts::PI + t2 - PHI2;
    let p = lam.cos() - z2;
    let q = lam.sin();
    let r = z3 * lam.cos() - z1;
    let gamma = q.atan2(p) - (r / (p * p + q * q).sqrt()).acos();
    t1 + t2 - PHI2 - gamma
}

/// x2 = ∂θa/∂θ2 by central differences of [`theta_a`].
pub fn x2(t2: f64) -> f64 {
    let h = 1e-6;
    (theta_a(0.0, t2 + h) - theta_a(0.0, t2 - h)) / (2.0 * h)
}

/// World point at distance k along phalanx 1 or 2.
pub fn point(ph: u8, t1: f64, t2: f64, k: f64) -> (f64, f64) {
    if ph == 1 {
        (k * t1.cos(), k * t1.sin())
    } else {
        (
            L1 * t1.cos() + k * (t1 + t2).cos(),
            L1 * t1.sin() + k * (t1 + t2).sin(),
        )
    }
}

/// Left normal of phalanx 1 or 2.
pub fn normal(ph: u8, t1: f64, t2: f64) -> (f64, f64) {
    let a = if ph == 1 { t1 } else { t1 + t2 };
    (-a.sin(), a.cos())
}

/// Signed distance from (x, y) to the line of phalanx `ph` (positive on the left) and the
/// projection k along it.
pub fn line_dist(ph: u8, t1: f64, t2: f64, x: f64, y: f64) -> (f64, f64) {
    let (bx, by) = point(ph, t1, t2, 0.0);
    let a = if ph == 1 { t1 } else { t1 + t2 };
    let (ux, uy) = (a.cos(), a.sin());
    let (rx, ry) = (x - bx, y - by);
    (rx * -uy + ry * ux, rx * ux + ry * uy)
}

/// Contact Jacobian [∂/∂θ1, ∂/∂θ2] of the normal displacement of the material point at k
/// (central differences of the forward kinematics, normal frozen).
pub fn jac(ph: u8, t1: f64, t2: f64, k: f64) -> [f64; 2] {
    let (nx, ny) = normal(ph, t1, t2);
    let h = 1e-6;
    let d = |a: (f64, f64), b: (f64, f64)| ((a.0 - b.0) * nx + (a.1 - b.1) * ny) / (2.0 * h);
    [
        d(point(ph, t1 + h, t2, k), point(ph, t1 - h, t2, k)),
        d(point(ph, t1, t2 + h, k), point(ph, t1, t2 - h, k)),
    ]
}

/// Spring energy (J).
pub fn energy(t1: f64, t2: f64) -> f64 {
    0.5 * K1 * (t1 - TH01).powi(2) + 0.5 * K2 * t2 * t2
}
