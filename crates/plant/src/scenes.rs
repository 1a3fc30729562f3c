//! Built-in scenes as `const` data (no parsing on the target). The TOML files in
//! `crates/plant/scenes/` describe the same scenes for the host tools.

use crate::drive::DriveParams;
use crate::kin::{Object, Phalanx};
use crate::path::ContactSpec;
use crate::scene::{CommandMode, CommandProfile, FaultSpec, ObjectSpec, Scene};

/// θ1 at contact of the paper's Table 2 scene (rad).
pub const TABLE2_THETA1_C_RAD: f64 = 1.2797;
/// Contact location of the Table 2 scene on the distal phalanx (m).
pub const TABLE2_K2_M: f64 = 0.02927;
/// Cylinder radius of the Table 2 scene (m).
pub const TABLE2_RADIUS_M: f64 = 0.05;

const fn touching(theta1_c_rad: f64, phalanx: Phalanx, k_c_m: f64, radius_m: f64) -> ObjectSpec {
    ObjectSpec::Touching(ContactSpec {
        theta1_c_rad,
        phalanx,
        k_c_m,
        radius_m,
    })
}

/// A duty ramp that closes the finger onto its object: 0 → 0.8 over 0.3 s, then held
/// (4.8 V: the motor stalls near 2 N·m at the base link).
const CLOSE: CommandProfile = CommandProfile {
    mode: CommandMode::Duty,
    from: 0.0,
    to: 0.8,
    t_start_s: 0.0,
    ramp_s: 0.3,
};

const fn scene(name: &'static str, object: ObjectSpec) -> Scene {
    Scene {
        name,
        object,
        command: CLOSE,
        duration_s: 5.0,
        ..Scene::DEFAULT
    }
}

/// The paper's Table 2 scene: cylinder R = 0.05 m touching the distal phalanx at
/// k2 = 0.02927 m when θ1 = 1.2797 rad. Realistic drive and sensors.
pub const fn table2() -> Scene {
    scene(
        "table2",
        touching(
            TABLE2_THETA1_C_RAD,
            Phalanx::Distal,
            TABLE2_K2_M,
            TABLE2_RADIUS_M,
        ),
    )
}

/// Names of all built-in scenes.
pub const NAMES: &[&str] = &[
    "table2",
    "table2_ideal",
    "free",
    "vertex_k2_10",
    "vertex_k2_30",
    "vertex_k2_50",
    "vertex_k2_70",
    "cyl10_k2_20",
    "cyl10_k2_50",
    "cyl30_k2_40",
    "proximal_vertex_k1_50",
    "large_cyl_second_contact",
    "large_cyl_cuts_proximal",
    "vertex_beyond_tip",
    "hard_stop_stall",
    "fault_encoder_stuck",
    "fault_encoder_jump",
    "fault_short",
    "fault_loss_of_contact",
    "fault_power_up_away",
    "fault_power_up_stuck_encoder",
];

/// A built-in scene by name (see [`NAMES`]).
pub fn by_name(name: &str) -> Option<Scene> {
    let t1 = TABLE2_THETA1_C_RAD;
    let s = match name {
        "table2" => table2(),
        "table2_ideal" => Scene {
            name: "table2_ideal",
            ..table2().ideal()
        },
        "free" => scene("free", ObjectSpec::None),
        // Vertices along the distal phalanx (k2 = 10 % … 70 % of l2 = 0.075 m), contact at θ1 = 1.2797.
        "vertex_k2_10" => scene("vertex_k2_10", touching(t1, Phalanx::Distal, 0.0075, 0.0)),
        "vertex_k2_30" => scene("vertex_k2_30", touching(t1, Phalanx::Distal, 0.0225, 0.0)),
        "vertex_k2_50" => scene("vertex_k2_50", touching(t1, Phalanx::Distal, 0.0375, 0.0)),
        "vertex_k2_70" => scene("vertex_k2_70", touching(t1, Phalanx::Distal, 0.0525, 0.0)),
        // Cylinders along the distal phalanx.
        "cyl10_k2_20" => scene("cyl10_k2_20", touching(t1, Phalanx::Distal, 0.015, 0.01)),
        "cyl10_k2_50" => scene("cyl10_k2_50", touching(t1, Phalanx::Distal, 0.0375, 0.01)),
        "cyl30_k2_40" => scene("cyl30_k2_40", touching(t1, Phalanx::Distal, 0.030, 0.03)),
        // A proximal contact.
        "proximal_vertex_k1_50" => scene(
            "proximal_vertex_k1_50",
            touching(1.0, Phalanx::Proximal, 0.05, 0.0),
        ),
        // A large cylinder (R = 5 cm) on the proximal phalanx near O2: as the torque rises the
        // distal phalanx wraps onto it (second contact, the finger locks).
        "large_cyl_second_contact" => scene(
            "large_cyl_second_contact",
            touching(1.0, Phalanx::Proximal, 0.08, 0.05),
        ),
        // A large cylinder (R = 9.75 cm) placed tangent to the distal phalanx near O2: it
        // already cuts the proximal phalanx there (MODEL.md trap), so the proximal phalanx
        // touches first and the distal one second.
        "large_cyl_cuts_proximal" => scene(
            "large_cyl_cuts_proximal",
            touching(t1, Phalanx::Distal, 0.010, 0.0975),
        ),
        // A vertex near the tip: the contact slides past the tip while the torque rises.
        "vertex_beyond_tip" => scene(
            "vertex_beyond_tip",
            touching(t1, Phalanx::Distal, 0.074, 0.0),
        ),
        // No object, duty ramped to −1 in 0.2 s: the finger opens onto its extension stops,
        // locks, and the motor stalls at 6 V / 20 Ω = 0.3 A (over-current above 0.28 A).
        "hard_stop_stall" => Scene {
            name: "hard_stop_stall",
            object: ObjectSpec::None,
            command: CommandProfile {
                mode: CommandMode::Duty,
                from: 0.0,
                to: -1.0,
                t_start_s: 0.0,
                ramp_s: 0.2,
            },
            duration_s: 2.0,
            ..Scene::DEFAULT
        },
        // Table 2 with the encoder freezing at 1.0 s (during the approach, motor turning).
        "fault_encoder_stuck" => Scene {
            name: "fault_encoder_stuck",
            faults: FaultSpec {
                encoder_stuck_at_s: 1.0,
                ..FaultSpec::NONE
            },
            ..table2()
        },
        // Table 2 with the encoder count jumping by +500 counts at 1.0 s (a glitch).
        "fault_encoder_jump" => Scene {
            name: "fault_encoder_jump",
            faults: FaultSpec {
                encoder_jump_at_s: 1.0,
                encoder_jump_counts: 500,
                ..FaultSpec::NONE
            },
            ..table2()
        },
        // Table 2 with the winding shorted to 2 Ω at 1.0 s: over-current.
        "fault_short" => Scene {
            name: "fault_short",
            faults: FaultSpec {
                short_at_s: 1.0,
                short_r_ohm: 2.0,
                ..FaultSpec::NONE
            },
            ..table2()
        },
        // Table 2 with the object removed at 3.5 s, after contact (loss of contact).
        "fault_loss_of_contact" => Scene {
            name: "fault_loss_of_contact",
            faults: FaultSpec {
                remove_object_at_s: 3.5,
                ..FaultSpec::NONE
            },
            ..table2()
        },
        // Table 2 with the finger powered up 0.45 rad flexed (as after a reset mid-approach),
        // the encoder reading 0 there.
        "fault_power_up_away" => Scene {
            name: "fault_power_up_away",
            faults: FaultSpec {
                power_up_offset_rad: 0.45,
                ..FaultSpec::NONE
            },
            duration_s: 20.0,
            ..table2()
        },
        // Powered up 0.3 rad flexed with the encoder stuck from the start: no rest can be
        // found (the count never shows the return to rest).
        "fault_power_up_stuck_encoder" => Scene {
            name: "fault_power_up_stuck_encoder",
            faults: FaultSpec {
                power_up_offset_rad: 0.3,
                encoder_stuck_at_s: 0.0,
                ..FaultSpec::NONE
            },
            duration_s: 25.0,
            ..table2()
        },
        _ => return None,
    };
    Some(s)
}

/// An object at a fixed world position (helper for tests and tools).
pub const fn fixed_object(x_m: f64, y_m: f64, radius_m: f64) -> ObjectSpec {
    ObjectSpec::At(Object { x_m, y_m, radius_m })
}

/// The realistic drive (re-exported for convenience).
pub const DRIVE: DriveParams = DriveParams::RE10_GP10A;
