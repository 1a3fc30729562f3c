//! Which estimator the controller's request names: the paper's two-point method or
//! `pathfit` on the whole contact-to-settle path. Both run inside the firmware's
//! `grasp::run_estimate_with`; the tool only picks `ControllerConfig::estimator`.

/// The estimator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Eq. 1: K̂c = ΔT_a/Δθa from the contact point and the settled end, inverted at contact.
    TwoPoint,
    /// The whole contact-to-settle path fitted with the quasi-static contact model.
    Pathfit,
}

impl Method {
    /// The controller's setting.
    pub fn estimator(self) -> grasp::Estimator {
        match self {
            Method::TwoPoint => grasp::Estimator::TwoPoint,
            Method::Pathfit => grasp::Estimator::PathFit,
        }
    }

    /// Name as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::TwoPoint => "two-point",
            Method::Pathfit => "pathfit",
        }
    }
}
