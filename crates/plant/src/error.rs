//! Typed errors of the plant. Nothing in this crate panics on data; every failure is one of these.

use core::fmt;

/// Why a plant operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlantError {
    /// A scene or finger value is non-physical; the payload is the scene key (e.g. `"drive.r_ohm"`).
    Invalid(&'static str),
    /// A value is NaN or infinite, or an angle is absurdly large.
    NonFinite,
    /// The four-bar cannot close at this θ2.
    NotAssemblable,
    /// The transmission is singular (toggle) here.
    Singular,
    /// An iterative solve did not converge.
    NoConvergence,
    /// The object already overlaps the finger at the rest pose, or the contact spec does not touch.
    BadPlacement,
    /// Path: the object also touches the other phalanx (second contact).
    SecondContact,
    /// Path: the contact point passed the tip of its phalanx.
    BeyondTip,
    /// Path: the contact point passed behind the lower joint of its phalanx.
    BehindJoint,
    /// Path: the contact force fell to zero (the finger left the object).
    LossOfContact,
    /// Path: a joint reached its mechanical stop.
    JointLimit,
    /// Path: the contact path folds (infinite stiffness): the finger jams against the object.
    Jammed,
    /// Unknown scene name or unknown key (std TOML loader: the key is in the message).
    Unknown(&'static str),
}

impl PlantError {
    /// snake_case name, stable, for JSON and logs.
    pub const fn kind(&self) -> &'static str {
        match self {
            PlantError::Invalid(_) => "invalid",
            PlantError::NonFinite => "non_finite",
            PlantError::NotAssemblable => "not_assemblable",
            PlantError::Singular => "singular",
            PlantError::NoConvergence => "no_convergence",
            PlantError::BadPlacement => "bad_placement",
            PlantError::SecondContact => "second_contact",
            PlantError::BeyondTip => "beyond_tip",
            PlantError::BehindJoint => "behind_joint",
            PlantError::LossOfContact => "loss_of_contact",
            PlantError::JointLimit => "joint_limit",
            PlantError::Jammed => "jammed",
            PlantError::Unknown(_) => "unknown",
        }
    }
}

impl fmt::Display for PlantError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PlantError::Invalid(key) => write!(f, "invalid value for `{key}`"),
            PlantError::Unknown(what) => write!(f, "unknown `{what}`"),
            other => f.write_str(other.kind()),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for PlantError {}
