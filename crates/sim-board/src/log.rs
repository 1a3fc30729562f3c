//! The simulated finger's plant events and truth in the integers of the firmware's log lines
//! (`proto::log::PLANT`, `proto::log::TRUTH`), for the QEMU board and the host runner alike.

use plant::{EventKind, Plant};

/// A plant event, in the integers of the log line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlantEventLine {
    /// snake_case name of the event kind.
    pub kind: &'static str,
    /// Simulated time (µs).
    pub t_us: u32,
    /// θa (µrad).
    pub theta_a_urad: i32,
    /// T_a (µN·m).
    pub torque_unm: i32,
    /// Contact location on the phalanx (µm), when the event has one (0 otherwise).
    pub k_um: i32,
    /// Phalanx name, when the event has one ("" otherwise).
    pub phalanx: &'static str,
}

impl PlantEventLine {
    /// The event's integers.
    pub fn of(e: &plant::Event) -> Self {
        let (phalanx, k_m) = match e.kind {
            EventKind::FirstContact { phalanx, k_m }
            | EventKind::LossOfContact { phalanx, k_m }
            | EventKind::SecondContact { phalanx, k_m } => (phalanx.name(), k_m),
            EventKind::BeyondTip { phalanx } | EventKind::BehindJoint { phalanx } => {
                (phalanx.name(), 0.0)
            }
            _ => ("", 0.0),
        };
        Self {
            kind: e.kind.name(),
            t_us: (e.t_s * 1e6) as u32,
            theta_a_urad: micro(e.theta_a_rad),
            torque_unm: micro(e.torque_nm),
            k_um: micro(k_m),
            phalanx,
        }
    }
}

/// The plant's truth, in the integers of the log line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TruthLine {
    /// Where it was taken ("settled", "end").
    pub at: &'static str,
    /// Simulated time (µs).
    pub t_us: u32,
    /// True θa (µrad).
    pub theta_a_urad: i32,
    /// True T_a (µN·m).
    pub torque_unm: i32,
    /// Contact state name.
    pub contact: &'static str,
    /// True contact location on its phalanx (µm).
    pub k_um: i32,
}

impl TruthLine {
    /// The truth of `plant` now, labelled `at`.
    pub fn of(plant: &Plant, at: &'static str) -> Self {
        let t = plant.truth();
        Self {
            at,
            t_us: (t.t_s * 1e6) as u32,
            theta_a_urad: micro(t.theta_a_rad),
            torque_unm: micro(t.torque_a_nm),
            contact: t.contact.name(),
            k_um: micro(t.k_m),
        }
    }
}

/// `v` × 10⁶, saturated to i32 (NaN → 0): SI to the log's µ-units.
pub fn micro(v: f64) -> i32 {
    let x = v * 1e6;
    if x.is_nan() {
        0
    } else {
        x.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }
}
