//! Which estimator the controller's request names: the paper's two-point method or
//! `pathfit` on the whole contact-to-settle path. Both run inside the firmware's
//! `grasp::run_estimate_with`; the tool only picks `ControllerConfig::estimator`.

/// The estimator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Eq. 1: K̂c = ΔT_a/Δθa from the contact point and the settled end, inverted at contact.
    TwoPoint,
    /// The whole contact-to-settle path fitted with the quasi-static contact model (the
    /// firmware's spelling; `pathfit` is accepted too).
    #[value(name = "path-fit", alias = "pathfit")]
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
            Method::Pathfit => "path-fit",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    /// One spelling with the firmware (`FINGER_FW_ESTIMATOR=path-fit`), the old one still read
    /// (command lines, `# pts-sim` lines of older traces).
    #[test]
    fn names_match_the_firmware_and_the_old_spelling_still_parses() {
        for m in Method::value_variants() {
            assert_eq!(Method::from_str(m.name(), false), Ok(*m));
        }
        assert_eq!(Method::Pathfit.name(), "path-fit");
        assert_eq!(Method::from_str("pathfit", false), Ok(Method::Pathfit));
        assert!(Method::from_str("path_fit", false).is_err());
    }
}
