//! The estimate on a segmented request with the host's own contact point and configuration.

use grasp::estimate::EstimateRequest;

/// The firmware's integer path fit on a segmented request with the contact point and the
/// path-fit configuration given by the caller (the host's per-recording identification),
/// instead of the controller's defaults and back-dating. `table` must be built for the
/// caller's configuration and the request's period; σ is graded against the table's l2 as the
/// controller's estimate does. Returns the result with σ(k2,c) (m) of a distal answer; a proximal path is reported as [`Located::Proximal`](grasp::Located).
pub fn path_fit_with(
    table: &pathfit::q::PathTable,
    req: &EstimateRequest,
    theta_a_c_rad: f64,
    ta_c_nm: f64,
) -> Result<(grasp::EstimateResult, Option<f64>), pathfit::PathFitError> {
    grasp::estimate::path_fit_q_at(table, req, theta_a_c_rad, ta_c_nm)
}
