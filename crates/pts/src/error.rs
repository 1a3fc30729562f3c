//! One error type for every failure of the model and the solver.

/// Why the model or the solver could not answer. Every variant is a reason, not a bug:
/// the solver never panics and never returns NaN inside `Ok`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PtsError {
    /// An input was NaN or infinite.
    NonFinite,
    /// An input was finite but outside the range the back end or the model accepts.
    OutOfRange,
    /// The finger description is not physical.
    InvalidFinger,
    /// The four-bar linkage cannot close at this θ2.
    NotAssemblable,
    /// Toggle: x2 ≈ 0, the actuator cannot drive θ2 here.
    Toggle,
    /// The linkage Jacobian is singular (dγ/dλ unbounded).
    Singular,
    /// An iterative solve did not converge within its iteration budget.
    NoConvergence,
    /// K_c(k2) is not monotone on the distal phalanx at this configuration:
    /// the inversion would be ambiguous.
    NotMonotone,
    /// Measured stiffness is below the free-motion stiffness (no contact can explain it).
    StiffnessBelowFree,
    /// Measured stiffness is above the stiffness of a contact at the distal tip.
    BeyondTip,
    /// The actuator moved too little (or backwards) during the step to measure a stiffness.
    DeltaThetaTooSmall,
    /// The torque step was zero or negative.
    DeltaTorqueNotPositive,
    /// The contact location is outside the phalanx (k ≤ 0 or k > l).
    ContactOutsidePhalanx,
    /// A fixed-point intermediate overflowed (saturated).
    Overflow,
    /// The inversion is too ill-conditioned here: a small error in K̂c moves k2 too far.
    IllConditioned,
}

impl PtsError {
    /// A stable snake_case name for logs and JSON.
    pub const fn kind(&self) -> &'static str {
        match self {
            PtsError::NonFinite => "non_finite",
            PtsError::OutOfRange => "out_of_range",
            PtsError::InvalidFinger => "invalid_finger",
            PtsError::NotAssemblable => "not_assemblable",
            PtsError::Toggle => "toggle",
            PtsError::Singular => "singular",
            PtsError::NoConvergence => "no_convergence",
            PtsError::NotMonotone => "not_monotone",
            PtsError::StiffnessBelowFree => "stiffness_below_free",
            PtsError::BeyondTip => "beyond_tip",
            PtsError::DeltaThetaTooSmall => "delta_theta_too_small",
            PtsError::DeltaTorqueNotPositive => "delta_torque_not_positive",
            PtsError::ContactOutsidePhalanx => "contact_outside_phalanx",
            PtsError::Overflow => "overflow",
            PtsError::IllConditioned => "ill_conditioned",
        }
    }
}

impl core::fmt::Display for PtsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let msg = match self {
            PtsError::NonFinite => "input is NaN or infinite",
            PtsError::OutOfRange => "input outside the accepted range",
            PtsError::InvalidFinger => "finger description is not physical",
            PtsError::NotAssemblable => "the four-bar linkage cannot close at this configuration",
            PtsError::Toggle => {
                "toggle configuration: x2 = 0, the actuator cannot drive the distal joint"
            }
            PtsError::Singular => "linkage Jacobian is singular",
            PtsError::NoConvergence => "iterative solve did not converge",
            PtsError::NotMonotone => {
                "K_c(k2) is not monotone on the distal phalanx here; inversion is ambiguous"
            }
            PtsError::StiffnessBelowFree => "stiffness below the free-motion stiffness",
            PtsError::BeyondTip => "stiffness above that of a contact at the distal tip",
            PtsError::DeltaThetaTooSmall => {
                "actuator displacement too small or negative to measure stiffness"
            }
            PtsError::DeltaTorqueNotPositive => "torque step is zero or negative",
            PtsError::ContactOutsidePhalanx => "contact location outside the phalanx",
            PtsError::Overflow => "fixed-point overflow",
            PtsError::IllConditioned => "inversion too ill-conditioned here",
        };
        f.write_str(msg)
    }
}

#[cfg(feature = "std")]
extern crate std;
#[cfg(feature = "std")]
impl std::error::Error for PtsError {}
