//! Following the finger as θa moves: active-set changes, each located by bisection.

use crate::kin::{Active, Constraint, Gap, Kin, Phalanx, Pose};
use crate::PlantError;

/// Bisection tolerance on θa for every event (rad). Events are reported at the feasible side
/// of the bracket, within this distance of the true crossing.
pub const EVENT_TOL_RAD: f64 = 1e-10;
const MAX_BISECT: usize = 80;
/// A constraint force (N or N·m) still this large where it "turns negative" marks a fold of
/// the constrained path, not a release.
const JAM_LAMBDA: f64 = 1e-3;

/// What happened to the finger.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EventKind {
    /// The object touched a phalanx (free → contact), at `k_m` from the phalanx's lower joint (m).
    FirstContact {
        /// Which phalanx.
        phalanx: Phalanx,
        /// Contact location (m).
        k_m: f64,
    },
    /// The contact force fell to zero and the finger left the object.
    LossOfContact {
        /// Which phalanx.
        phalanx: Phalanx,
        /// Contact location at release (m).
        k_m: f64,
    },
    /// The contact point passed the distal end of its phalanx (k > l).
    BeyondTip {
        /// Which phalanx.
        phalanx: Phalanx,
    },
    /// The contact point passed behind the lower joint of its phalanx (k < 0).
    ///
    /// Detected and bisected like [`EventKind::BeyondTip`], but for this kinematic class it
    /// cannot be reached quasi-statically from a free-motion contact: along a distal contact
    /// `dk2 = dθ2·[l1 sin θ2·s + R(1 − s)]` with `s = k2/(l1 cos θ2 + k2)`, which for a vertex is
    /// proportional to k2 (k2 → 0 only asymptotically) and for a cylinder is positive; a
    /// proximal contact keeps θ1, hence k1, fixed. No built-in scene triggers it.
    BehindJoint {
        /// Which phalanx.
        phalanx: Phalanx,
    },
    /// The object also touches the other phalanx: the finger is locked.
    SecondContact {
        /// The phalanx touched second.
        phalanx: Phalanx,
        /// Its contact location (m).
        k_m: f64,
    },
    /// A joint reached a mechanical stop.
    JointLimit {
        /// Which stop.
        constraint: Constraint,
    },
    /// A joint left its stop.
    LimitReleased {
        /// Which stop.
        constraint: Constraint,
    },
    /// The constrained path folds (dθa/dθ2 = 0: infinite stiffness, e.g. a phalanx corner pushing
    /// straight into a small cylinder): the finger is locked as by a second constraint.
    Jammed {
        /// The constraint whose path folded.
        constraint: Constraint,
    },
    /// A locked finger unloaded below its lock angle.
    Unlocked,
    /// The plant's solver failed and the plant froze its geometry (typed reason).
    SolverFailure(PlantError),
    /// The motor current exceeded the scene's over-current threshold (A).
    OverCurrent {
        /// Current (A).
        current_a: f64,
    },
}

impl EventKind {
    /// snake_case name for logs and CSV.
    pub const fn name(&self) -> &'static str {
        match self {
            EventKind::FirstContact { .. } => "first_contact",
            EventKind::LossOfContact { .. } => "loss_of_contact",
            EventKind::BeyondTip { .. } => "beyond_tip",
            EventKind::BehindJoint { .. } => "behind_joint",
            EventKind::SecondContact { .. } => "second_contact",
            EventKind::JointLimit { .. } => "joint_limit",
            EventKind::LimitReleased { .. } => "limit_released",
            EventKind::Jammed { .. } => "jammed",
            EventKind::Unlocked => "unlocked",
            EventKind::SolverFailure(_) => "solver_failure",
            EventKind::OverCurrent { .. } => "over_current",
        }
    }
}

/// An event with where it happened.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Event {
    /// Simulated time (s), interpolated inside the control period on θa; 0 for quasi-static paths.
    pub t_s: f64,
    /// θa at the event (rad), bisected to [`EVENT_TOL_RAD`].
    pub theta_a_rad: f64,
    /// T_a at the event (N·m).
    pub torque_nm: f64,
    /// θ1 at the event (rad).
    pub theta1_rad: f64,
    /// θ2 at the event (rad).
    pub theta2_rad: f64,
    /// What.
    pub kind: EventKind,
}

/// The solver plus its history: current pose, active set and which constraints are armed.
#[derive(Clone, Copy, Debug)]
pub struct Tracker {
    /// The solver.
    pub kin: Kin,
    /// Last accepted pose.
    pub pose: Pose,
    armed: [bool; 6],
    /// dθ2/dθa of the last accepted move in the same active set (predictor for Newton).
    slope: f64,
}

/// The event of constraint `c` letting go: a lost contact (at `k_m`) or a released limit.
fn released(c: Constraint, k_m: f64) -> EventKind {
    match c {
        Constraint::Contact(ph) => EventKind::LossOfContact { phalanx: ph, k_m },
        other => EventKind::LimitReleased { constraint: other },
    }
}

/// What a new constraint did to a pass of [`Tracker::advance`].
enum Hit {
    /// The tracker moved to the event's pose: solve again from there.
    Again,
    /// A third constraint on a locked finger: the pose stands.
    Locked,
}

impl Tracker {
    /// Starts at the rest pose; fails if the object already overlaps the finger there.
    pub fn new(kin: Kin) -> Result<Self, PlantError> {
        let pose = kin.rest()?;
        let mut t = Self {
            kin,
            pose,
            armed: [false; 6],
            slope: 0.0,
        };
        for c in Constraint::ALL {
            if let Some(g) = kin.gap(c, pose.theta1_rad, pose.theta2_rad) {
                if g.gap < 0.0 && matches!(c, Constraint::Contact(_)) && in_segment(&kin, c, g.k_m)
                {
                    return Err(PlantError::BadPlacement);
                }
                t.armed[c.slot()] = g.gap >= 0.0;
            }
        }
        Ok(t)
    }

    /// Starts at a given free pose (θa) without checks other than arming (for paths).
    pub fn at(kin: Kin, pose: Pose) -> Self {
        let mut t = Self {
            kin,
            pose,
            armed: [false; 6],
            slope: 0.0,
        };
        t.rearm();
        t
    }

    fn rearm(&mut self) {
        let gaps = self.kin.gaps(self.pose.theta1_rad, self.pose.theta2_rad);
        self.rearm_with(&gaps);
    }

    fn rearm_with(&mut self, gaps: &[Option<Gap>; 6]) {
        for c in Constraint::ALL {
            let active = match self.pose.active {
                Active::One(a) => a == c,
                Active::Two { first, second, .. } => first == c || second == c,
                Active::None => false,
            };
            if active {
                self.armed[c.slot()] = false;
                continue;
            }
            if let Some(g) = gaps.get(c.slot()).copied().flatten() {
                if !g.left || g.gap < -1e-9 {
                    self.armed[c.slot()] = false;
                } else if g.gap >= 0.0 {
                    self.armed[c.slot()] = true;
                }
            }
        }
    }

    /// Moves the finger to θa (rad), reporting every event in order through `emit`.
    /// On error the tracker keeps its last good pose.
    ///
    /// Each pass solves toward the target in the current constraint set, then handles the
    /// first event along the move (a release, the contact leaving its phalanx, a new
    /// constraint), restarting from the event's pose, until a pass meets none.
    pub fn advance(
        &mut self,
        theta_a_rad: f64,
        emit: &mut dyn FnMut(Event),
    ) -> Result<Pose, PlantError> {
        for _ in 0..8 {
            let old = self.pose;
            let Some(p) = self.solve_toward(old, theta_a_rad, emit)? else {
                continue;
            };
            if self.release(old, p, theta_a_rad, emit)? {
                continue;
            }
            if self.leave_phalanx(old, p, theta_a_rad, emit)? {
                continue;
            }
            let gaps = self.kin.gaps(p.theta1_rad, p.theta2_rad);
            match self.new_constraint(old, p, &gaps, theta_a_rad, emit)? {
                Some(Hit::Again) => continue,
                Some(Hit::Locked) => return Ok(p),
                None => {}
            }
            let dth = p.theta_a_rad - old.theta_a_rad;
            self.slope = if p.active == old.active && dth.abs() > 1e-12 {
                (p.theta2_rad - old.theta2_rad) / dth
            } else {
                0.0
            };
            self.pose = p;
            self.rearm_with(&gaps);
            return Ok(p);
        }
        Err(PlantError::NoConvergence)
    }

    /// The pose at θa in the current constraint set; `None` when that set stopped existing
    /// inside the move and the tracker moved on (snapped off into free motion, or jammed).
    fn solve_toward(
        &mut self,
        old: Pose,
        theta_a_rad: f64,
        emit: &mut dyn FnMut(Event),
    ) -> Result<Option<Pose>, PlantError> {
        // While a contact is inside its phalanx, solve against the phalanx's whole line so
        // that a contact about to leave the segment is still solvable and can be bisected.
        let line = match old.active {
            Active::One(c @ Constraint::Contact(ph)) if (0.0..=self.len(ph)).contains(&old.k_m) => {
                Some(c)
            }
            _ => None,
        };
        // First-order predictor from the last move: saves a Newton evaluation per step.
        let guess = old.theta2_rad + self.slope * (theta_a_rad - old.theta_a_rad);
        let guess = if guess.is_finite() && (guess - old.theta2_rad).abs() < 0.1 {
            guess
        } else {
            old.theta2_rad
        };
        let solved = match (line, old.active) {
            (Some(c), _) => self.kin.solve_one(theta_a_rad, c, guess, true),
            // Locked: the geometry is frozen; only the structural spring moves.
            (
                None,
                Active::Two {
                    theta_a_rad: ta_lock,
                    torque_nm,
                    ..
                },
            ) => Ok(Pose {
                theta_a_rad,
                torque_nm: torque_nm + self.kin.finger.k_lock_nm_per_rad * (theta_a_rad - ta_lock),
                ..old
            }),
            (None, _) => self.kin.solve(theta_a_rad, old.active, guess),
        };
        match (solved, old.active) {
            (Ok(p), _) => Ok(Some(p)),
            (Err(_), Active::One(c)) => {
                // The constrained configuration stopped existing inside this step. Find the
                // last solvable pose; if the free finger at the target clears the object it
                // snapped off (a cylinder slipping off a corner), otherwise it is jammed.
                let at = self.bisect(old, theta_a_rad, |k, pose| {
                    Ok(match k.solve(pose, old.active, old.theta2_rad) {
                        Ok(q) if q.lambda >= 0.0 => (1.0, q),
                        _ => (-1.0, old),
                    })
                })?;
                let free = self.kin.solve(theta_a_rad, Active::None, at.theta2_rad);
                let clear = free.as_ref().is_ok_and(|f| {
                    self.kin
                        .gap(c, f.theta1_rad, f.theta2_rad)
                        .is_none_or(|g| g.gap >= 0.0)
                });
                match free {
                    Ok(f) if clear => {
                        emit(ev(&at, released(c, at.k_m)));
                        self.pose = f;
                        self.slope = 0.0;
                        self.rearm();
                    }
                    _ => self.jam(at, c, theta_a_rad, emit),
                }
                Ok(None)
            }
            (Err(e), _) => Err(e),
        }
    }

    /// Step 1 of a pass: release of the active constraint (λ < 0), or unlocking on reversal;
    /// `true` when it happened and the tracker moved to the event.
    fn release(
        &mut self,
        old: Pose,
        p: Pose,
        theta_a_rad: f64,
        emit: &mut dyn FnMut(Event),
    ) -> Result<bool, PlantError> {
        // 1. Release of the active constraint.
        match old.active {
            Active::One(c) if p.lambda < 0.0 => {
                let at = self.bisect(old, theta_a_rad, |k, pose| {
                    // Unsolvable counts as past the event.
                    Ok(match k.solve(pose, old.active, old.theta2_rad) {
                        Ok(q) => (q.lambda, q),
                        Err(_) => (-1.0, old),
                    })
                })?;
                if at.lambda > JAM_LAMBDA {
                    // λ jumped from large positive to negative: not a release but a fold of
                    // the contact path (infinite stiffness, the Newton branch switched).
                    self.jam(at, c, theta_a_rad, emit);
                    return Ok(true);
                }
                emit(ev(&at, released(c, at.k_m)));
                self.pose = self
                    .kin
                    .solve(at.theta_a_rad, Active::None, at.theta2_rad)?;
                self.rearm();
                return Ok(true);
            }
            Active::Two {
                first,
                theta_a_rad: ta_lock,
                dir,
                ..
            } if (theta_a_rad - ta_lock) * f64::from(dir) < 0.0 => {
                match self.kin.solve(ta_lock, Active::One(first), old.theta2_rad) {
                    Ok(at) => {
                        emit(ev(&at, EventKind::Unlocked));
                        self.pose = at;
                    }
                    // The first constraint has no solution at the lock (a jam): release
                    // into free motion at the lock angle.
                    Err(_) => {
                        let free = self.kin.solve(ta_lock, Active::None, old.theta2_rad)?;
                        emit(ev(&free, EventKind::Unlocked));
                        if let Constraint::Contact(ph) = first {
                            emit(ev(
                                &free,
                                EventKind::LossOfContact {
                                    phalanx: ph,
                                    k_m: old.k_m,
                                },
                            ));
                        }
                        self.pose = free;
                    }
                }
                self.slope = 0.0;
                self.rearm();
                return Ok(true);
            }
            _ => {}
        }
        Ok(false)
    }

    /// Step 2 of a pass: the contact point leaving its phalanx (past the tip or behind the
    /// joint); `true` when it happened.
    fn leave_phalanx(
        &mut self,
        old: Pose,
        p: Pose,
        theta_a_rad: f64,
        emit: &mut dyn FnMut(Event),
    ) -> Result<bool, PlantError> {
        // 2. The contact point leaving its phalanx.
        if let Active::One(Constraint::Contact(ph)) = old.active {
            let len = self.len(ph);
            let was_in = (0.0..=len).contains(&old.k_m);
            if was_in && !(0.0..=len).contains(&p.k_m) {
                let beyond = p.k_m > len;
                let at = self.bisect(old, theta_a_rad, |k, pose| {
                    let c = Constraint::Contact(ph);
                    let q = k.solve_one(pose, c, old.theta2_rad, true)?;
                    let ind = if beyond { len - q.k_m } else { q.k_m };
                    Ok((ind, q))
                })?;
                let kind = if beyond {
                    EventKind::BeyondTip { phalanx: ph }
                } else {
                    EventKind::BehindJoint { phalanx: ph }
                };
                emit(ev(&at, kind));
                let vertex = self.kin.object.is_none_or(|o| o.radius_m <= 0.0);
                if vertex {
                    // A vertex slips off the end: the phalanx is free again.
                    emit(ev(
                        &at,
                        EventKind::LossOfContact {
                            phalanx: ph,
                            k_m: at.k_m,
                        },
                    ));
                    let mut free = self
                        .kin
                        .solve(at.theta_a_rad, Active::None, at.theta2_rad)?;
                    free.theta_a_rad = at.theta_a_rad;
                    self.pose = free;
                    self.armed[Constraint::Contact(ph).slot()] = false;
                } else {
                    // Nudge the stored k just past the end so this event fires once; a
                    // cylinder now rests on the corner of the phalanx.
                    let mut q = at;
                    q.k_m = if beyond { len + 1e-12 } else { -1e-12 };
                    self.pose = q;
                }
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Step 3 of a pass: a new constraint becoming active, the earliest one along the move.
    fn new_constraint(
        &mut self,
        old: Pose,
        p: Pose,
        gaps: &[Option<Gap>; 6],
        theta_a_rad: f64,
        emit: &mut dyn FnMut(Event),
    ) -> Result<Option<Hit>, PlantError> {
        // 3. A new constraint becomes active: take the earliest one along the move.
        let mut first_hit: Option<(Pose, Constraint, f64)> = None;
        for c in Constraint::ALL {
            if !self.armed[c.slot()] {
                continue;
            }
            let Some(g) = gaps.get(c.slot()).copied().flatten() else {
                continue;
            };
            if g.gap >= 0.0 {
                continue;
            }
            let at = self.bisect(old, theta_a_rad, |k, pose| {
                let q = k.solve(pose, old.active, old.theta2_rad)?;
                let g = k
                    .gap(c, q.theta1_rad, q.theta2_rad)
                    .ok_or(PlantError::BadPlacement)?;
                Ok((g.gap, q))
            })?;
            let dist = (at.theta_a_rad - old.theta_a_rad).abs();
            if first_hit.is_none_or(|(_, _, d)| dist < d) {
                first_hit = Some((at, c, dist));
            }
        }
        if let Some((at, c, _)) = first_hit {
            let k_m = self
                .kin
                .gap(c, at.theta1_rad, at.theta2_rad)
                .map_or(0.0, |g| g.k_m);
            match old.active {
                Active::None => {
                    let kind = match c {
                        Constraint::Contact(ph) => EventKind::FirstContact { phalanx: ph, k_m },
                        other => EventKind::JointLimit { constraint: other },
                    };
                    emit(ev(&at, kind));
                    let mut q = self.kin.balance(at.theta_a_rad, at.theta2_rad, c)?;
                    q.lambda = q.lambda.max(0.0);
                    self.pose = q;
                }
                Active::One(first) => {
                    let kind = match c {
                        Constraint::Contact(ph) => EventKind::SecondContact { phalanx: ph, k_m },
                        other => EventKind::JointLimit { constraint: other },
                    };
                    emit(ev(&at, kind));
                    let mut q = at;
                    q.active = Active::Two {
                        first,
                        second: c,
                        theta_a_rad: at.theta_a_rad,
                        torque_nm: at.torque_nm,
                        dir: if theta_a_rad >= old.theta_a_rad {
                            1
                        } else {
                            -1
                        },
                    };
                    self.pose = q;
                }
                Active::Two { .. } => {
                    // Already locked: a third constraint changes nothing in the model.
                    self.pose = p;
                    self.rearm();
                    return Ok(Some(Hit::Locked));
                }
            }
            self.armed[c.slot()] = false;
            return Ok(Some(Hit::Again));
        }
        Ok(None)
    }

    /// Locks the finger at `at`: the path of constraint `c` folds there (dθa/dθ2 = 0, the
    /// stiffness is infinite), so it behaves like a second constraint.
    fn jam(&mut self, at: Pose, c: Constraint, target: f64, emit: &mut dyn FnMut(Event)) {
        emit(ev(&at, EventKind::Jammed { constraint: c }));
        self.pose = Pose {
            active: Active::Two {
                first: c,
                second: c,
                theta_a_rad: at.theta_a_rad,
                torque_nm: at.torque_nm,
                dir: if target >= at.theta_a_rad { 1 } else { -1 },
            },
            ..at
        };
        self.slope = 0.0;
    }

    fn len(&self, ph: Phalanx) -> f64 {
        match ph {
            Phalanx::Proximal => self.kin.finger.l1_m,
            Phalanx::Distal => self.kin.finger.l2_m,
        }
    }

    /// Bisection on θa between the accepted pose (indicator ≥ 0) and `target` (indicator < 0).
    /// Returns the pose on the feasible side, within [`EVENT_TOL_RAD`] of the crossing.
    fn bisect(
        &self,
        old: Pose,
        target: f64,
        mut ind: impl FnMut(&Kin, f64) -> Result<(f64, Pose), PlantError>,
    ) -> Result<Pose, PlantError> {
        let mut lo = old.theta_a_rad;
        let mut lo_pose = old;
        let mut hi = target;
        for _ in 0..MAX_BISECT {
            if (hi - lo).abs() <= EVENT_TOL_RAD {
                break;
            }
            let mid = 0.5 * (lo + hi);
            let (v, q) = ind(&self.kin, mid)?;
            if v >= 0.0 {
                lo = mid;
                lo_pose = q;
            } else {
                hi = mid;
            }
        }
        Ok(lo_pose)
    }
}

fn in_segment(kin: &Kin, c: Constraint, k: f64) -> bool {
    match c {
        Constraint::Contact(Phalanx::Proximal) => (0.0..=kin.finger.l1_m).contains(&k),
        Constraint::Contact(Phalanx::Distal) => (0.0..=kin.finger.l2_m).contains(&k),
        _ => true,
    }
}

pub(crate) fn ev(p: &Pose, kind: EventKind) -> Event {
    Event {
        t_s: 0.0,
        theta_a_rad: p.theta_a_rad,
        torque_nm: p.torque_nm,
        theta1_rad: p.theta1_rad,
        theta2_rad: p.theta2_rad,
        kind,
    }
}
