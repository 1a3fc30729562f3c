//! `pts estimate --trace`: replays a recorded grasp through the controller and estimator the
//! firmware runs (`grasp::Controller` + `grasp::run_estimate_with`).
//!
//! Each trace row becomes one control tick: the controller reads the row's encoder count and
//! ADC code (the raw columns when the trace has them, otherwise θa and T_a converted back with
//! the finger's drive constants), runs its state machine (calibration, approach, contact
//! detection, step, settle) and, when the step has settled, the estimate runs on the request
//! it hands out. The duty it computes is ignored: the trace already holds what happened.

use crate::trace::{state_name, Trace};
use grasp::{
    Controller, ControllerConfig, DriveConfig, EstimateResult, Hardware, State, TickOutput,
};
use pts::config::FingerFile;
use sim_board::run::{Board, Limits, Observer, Timing};

/// Settings of a `pts sim` run or a `pts board record`ing, written as a `# pts-sim key=value …`
/// comment line at the top of the CSV so that a replay uses the same controller settings and
/// drive constants.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TraceMeta {
    /// ΔT_a commanded (N·m).
    pub dta_nm: f64,
    /// Control period (s).
    pub dt_s: f64,
    /// The drive constants the controller was built with, when recorded.
    pub drive: Option<MetaDrive>,
    /// Controller settings that differed from grasp's defaults, when recorded.
    pub controller: MetaController,
}

/// The step ramp (N·m/s) of a `# pts-sim` line that does not state one: written before the
/// ramp was always recorded, when the controller's default ramped ΔT_a at this rate.
const LEGACY_STEP_RAMP_NM_PER_S: f64 = 1.0;

/// Controller settings in a `# pts-sim` line (a device's settings at the recorded grasp);
/// `None` = grasp's default.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MetaController {
    /// The estimator the recording ran.
    pub estimator: Option<crate::method::Method>,
    /// ΔT_a ramp rate (N·m/s); 0 = a step in one tick.
    pub step_ramp_nm_per_s: Option<f64>,
    /// Largest approach speed (rad/s).
    pub approach_speed_rad_s: Option<f64>,
    /// Approach torque ceiling (N·m).
    pub approach_max_nm: Option<f64>,
    /// Whether the contact was seated before the step.
    pub seating: Option<bool>,
}

impl MetaController {
    /// These settings applied to a controller configuration.
    pub fn apply(&self, mut c: ControllerConfig) -> ControllerConfig {
        if let Some(m) = self.estimator {
            c.estimator = m.estimator();
        }
        if let Some(r) = self.step_ramp_nm_per_s {
            c.step_shape = if r > 0.0 {
                grasp::StepShape::Ramp(r)
            } else {
                grasp::StepShape::Step
            };
        }
        if let Some(v) = self.approach_speed_rad_s {
            c.approach_speed_max_rad_s = v;
        }
        if let Some(v) = self.approach_max_nm {
            c.approach_max_nm = v;
        }
        if let Some(v) = self.seating {
            c.seating = v;
        }
        c
    }
}

/// Drive constants in a `# pts-sim` line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetaDrive {
    /// Motor turns per θa turn.
    pub gear_ratio: f64,
    /// Efficiency (driving).
    pub efficiency: f64,
    /// Torque constant (N·m/A).
    pub kt_nm_per_a: f64,
    /// Terminal resistance (Ω).
    pub resistance_ohm: f64,
    /// Bridge supply (V).
    pub bus_v: f64,
    /// Encoder counts per motor turn (×4).
    pub counts_per_rev: f64,
    /// A per ADC code.
    pub amps_per_code: f64,
    /// ADC code at zero current.
    pub zero_code: f64,
    /// Effective inertia at the crank (kg·m²), when the recorder knew it.
    pub inertia_kgm2: Option<f64>,
    /// Backlash at the crank (rad), when the recorder knew it.
    pub backlash_rad: Option<f64>,
}

impl MetaDrive {
    /// From the controller's drive configuration.
    pub fn of(d: &DriveConfig) -> Self {
        MetaDrive {
            gear_ratio: d.gear_ratio,
            efficiency: d.efficiency,
            kt_nm_per_a: d.kt_nm_per_a,
            resistance_ohm: d.resistance_ohm,
            bus_v: d.bus_v,
            counts_per_rev: d.encoder_counts_per_rev,
            amps_per_code: d.amps_per_code,
            zero_code: d.adc_zero_code,
            inertia_kgm2: Some(d.inertia_kgm2),
            backlash_rad: Some(d.backlash_rad),
        }
    }

    /// Puts these constants into a finger description; `Err` names what does not fit.
    pub fn apply(&self, f: &mut FingerFile) -> Result<(), String> {
        let int = |v: f64, what: &str| -> Result<u32, String> {
            (v.fract() == 0.0 && v >= 0.0 && v <= f64::from(u32::MAX))
                .then_some(v as u32)
                .ok_or_else(|| format!("{what} = {v} is not a count"))
        };
        f.drive.gear_ratio = self.gear_ratio;
        f.drive.efficiency = self.efficiency;
        f.motor.kt_nm_per_a = self.kt_nm_per_a;
        f.motor.resistance_ohm = self.resistance_ohm;
        f.motor.supply_v = self.bus_v;
        f.encoder.counts_per_rev = int(self.counts_per_rev, "counts_per_rev")?;
        f.current_sense.amps_per_count = self.amps_per_code;
        f.current_sense.zero_count = int(self.zero_code, "zero_code")?;
        if let Some(v) = self.inertia_kgm2 {
            f.drive.inertia_kgm2 = v;
        }
        if let Some(v) = self.backlash_rad {
            f.drive.backlash_rad = v;
        }
        Ok(())
    }
}

impl TraceMeta {
    /// The comment line.
    pub fn line(&self) -> String {
        let mut s = format!("# pts-sim dta_nm={} dt_s={}", self.dta_nm, self.dt_s);
        if let Some(d) = &self.drive {
            s += &format!(
                " gear_ratio={} efficiency={} kt_nm_per_a={} resistance_ohm={} bus_v={} \
                 counts_per_rev={} amps_per_code={} zero_code={}",
                d.gear_ratio,
                d.efficiency,
                d.kt_nm_per_a,
                d.resistance_ohm,
                d.bus_v,
                d.counts_per_rev,
                d.amps_per_code,
                d.zero_code
            );
            for (k, v) in [
                ("inertia_kgm2", d.inertia_kgm2),
                ("backlash_rad", d.backlash_rad),
            ] {
                if let Some(v) = v {
                    s += &format!(" {k}={v}");
                }
            }
        }
        let c = &self.controller;
        if let Some(m) = c.estimator {
            s += &format!(" estimator={}", m.name());
        }
        for (k, v) in [
            ("step_ramp_nm_per_s", c.step_ramp_nm_per_s),
            ("approach_speed_rad_s", c.approach_speed_rad_s),
            ("approach_max_nm", c.approach_max_nm),
        ] {
            if let Some(v) = v {
                s += &format!(" {k}={v}");
            }
        }
        if let Some(v) = c.seating {
            s += &format!(" seating={}", u8::from(v));
        }
        s
    }

    /// Finds the comment line in a CSV text.
    pub fn find(text: &str) -> Option<TraceMeta> {
        let line = text.lines().take(5).find(|l| l.starts_with("# pts-sim"))?;
        let get = |k: &str| {
            line.split_whitespace()
                .find_map(|w| w.strip_prefix(k)?.strip_prefix('='))
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite() && *v >= 0.0)
        };
        let drive = (|| {
            Some(MetaDrive {
                gear_ratio: get("gear_ratio")?,
                efficiency: get("efficiency")?,
                kt_nm_per_a: get("kt_nm_per_a")?,
                resistance_ohm: get("resistance_ohm")?,
                bus_v: get("bus_v")?,
                counts_per_rev: get("counts_per_rev")?,
                amps_per_code: get("amps_per_code")?,
                zero_code: get("zero_code")?,
                inertia_kgm2: get("inertia_kgm2"),
                backlash_rad: get("backlash_rad"),
            })
        })();
        let estimator = line
            .split_whitespace()
            .find_map(|w| w.strip_prefix("estimator="))
            .and_then(|v| <crate::method::Method as clap::ValueEnum>::from_str(v, true).ok());
        // Both are written out now; a line without them was written when every controller
        // seated unless told not to and ramped ΔT_a at the default of that time.
        let seating = Some(get("seating").is_none_or(|v| v != 0.0));
        let step_ramp_nm_per_s = get("step_ramp_nm_per_s").or(Some(LEGACY_STEP_RAMP_NM_PER_S));
        Some(TraceMeta {
            dta_nm: get("dta_nm").filter(|v| *v > 0.0)?,
            dt_s: get("dt_s").filter(|v| *v > 0.0)?,
            drive,
            controller: MetaController {
                estimator,
                step_ramp_nm_per_s,
                approach_speed_rad_s: get("approach_speed_rad_s").filter(|v| *v > 0.0),
                approach_max_nm: get("approach_max_nm").filter(|v| *v > 0.0),
                seating,
            },
        })
    }
}

/// What the replay found.
#[derive(Clone, Debug)]
pub struct Replay {
    /// The estimate, or the estimator's refusal; `None` when no step settled.
    pub estimate: Option<Result<EstimateResult, crate::sim::EstError>>,
    /// Trace time of the back-dated contact instant (s).
    pub contact_t_s: Option<f64>,
    /// (t, θa,c, T_a,c) of the contact the controller used.
    pub contact: Option<(f64, f64, f64)>,
    /// Final controller state.
    pub state: State,
    /// State after each row (for plots).
    pub states: Vec<String>,
    /// Control period used (s).
    pub dt_s: f64,
    /// Whether the raw encoder/ADC columns were used (exact replay).
    pub raw: bool,
    /// Notes for the user.
    pub warnings: Vec<String>,
}

/// The controller for a finger description and a control period: the one conversion the
/// firmware's build uses too ([`ControllerConfig::with_finger_file`]), so the replay sees the
/// finger, the drive, the rest angle and the current limit the firmware would.
pub fn controller_config(f: &FingerFile, dt_s: f64) -> Result<ControllerConfig, String> {
    ControllerConfig::DEFAULT
        .with_finger_file(f, dt_s)
        .map_err(|e| format!("finger for the controller: {e}"))
}

/// The controller's drive constants from a finger description and a control period.
pub fn drive_config(f: &FingerFile, dt_s: f64) -> Result<DriveConfig, String> {
    controller_config(f, dt_s).map(|c| c.drive)
}

/// Feeds the recorded rows to the controller, one a tick, and records what it did.
struct ReplayFeed<'a> {
    trace: &'a Trace,
    finger: &'a FingerFile,
    /// The rows carry raw encoder counts and ADC codes.
    raw: bool,
    /// θa at rest (rad).
    rest: f64,
    /// Control period (s).
    dt: f64,
    /// The controller's drive (the path fit's measurement model).
    drive: grasp::DriveConfig,
    rep: &'a mut Replay,
    /// Rounding error carried to the next ADC code (codes).
    dither: f64,
    /// Rows more than 1.5 periods after the previous one.
    gaps: usize,
}

impl Observer<TraceHw> for ReplayFeed<'_> {
    fn before_tick(&mut self, n: u64, ctl: &Controller, hw: &mut TraceHw) -> bool {
        let tr = self.trace;
        let Some(i) = usize::try_from(n).ok().filter(|&i| i < tr.len()) else {
            return false;
        };
        let prev = i.checked_sub(1).and_then(|p| tr.t_s.get(p));
        if prev.is_some_and(|p| tr.t_s[i] - p > 1.5 * self.dt) {
            self.gaps += 1;
        }
        if self.raw {
            hw.count = tr.encoder_count(i).unwrap_or(0);
            hw.code = tr.current_code(i).unwrap_or(0);
        } else {
            let finger = self.finger;
            let counts = ((tr.theta_a_rad[i] - self.rest) / finger.rad_per_count()).round();
            hw.count = (counts.clamp(-1e15, 1e15) as i64).rem_euclid(65536) as u16;
            // The recorded torque is already offset-corrected: feed the nominal zero while
            // the controller calibrates (bridge off), so that its offset is the nominal one
            // and it reads back the recorded torque. Sub-code values are dithered (error
            // feedback) so that the torque loop's integrator sees no rounding bias.
            let zero = f64::from(finger.current_sense.zero_count);
            let exact = if matches!(ctl.state(), State::Init | State::Calibrating) {
                zero
            } else {
                zero + finger.current_from_torque(tr.torque_nm[i])
                    / finger.current_sense.amps_per_count
            };
            let code = (exact + self.dither).round().clamp(0.0, 4095.0);
            self.dither += exact - code;
            self.dither = self.dither.clamp(-1.0, 1.0);
            hw.code = code as u16;
        }
        true
    }

    fn estimate(
        &mut self,
        req: &grasp::EstimateRequest,
        _hw: &TraceHw,
    ) -> Result<EstimateResult, grasp::EstimateError> {
        let r = grasp::run_estimate_with_reference(&self.finger.finger, &self.drive, req);
        self.rep.estimate = Some(r.map_err(|e| crate::sim::EstError::new(e.kind(), &e)));
        r
    }

    fn event(&mut self, e: grasp::Event, _hw: &TraceHw) {
        if let grasp::Event::ContactDetected {
            contact_tick,
            theta_a_urad,
            torque_unm,
            ..
        } = e
        {
            // Tick n is row n−1 (ticks count from 1).
            let idx = (contact_tick as usize).saturating_sub(1);
            let t_s = &self.trace.t_s;
            let t_first = t_s.first().copied().unwrap_or(0.0);
            let t = t_s
                .get(idx)
                .copied()
                .unwrap_or(t_first + f64::from(contact_tick) * self.dt);
            self.rep.contact_t_s = Some(t);
            self.rep.contact = Some((
                t,
                f64::from(theta_a_urad) / 1e6,
                f64::from(torque_unm) / 1e6,
            ));
        }
    }

    fn after_tick(&mut self, _n: u64, _out: &TickOutput, ctl: &Controller, _hw: &TraceHw) {
        self.rep.states.push(state_name(ctl.state()));
    }
}

/// A recording drives nothing: the next row is the next period.
impl Board for TraceHw {
    fn advance(&mut self) {}
}

struct TraceHw {
    count: u16,
    code: u16,
}

impl Hardware for TraceHw {
    fn encoder_count(&mut self) -> u16 {
        self.count
    }
    fn current_raw(&mut self) -> u16 {
        self.code
    }
    fn set_duty(&mut self, _duty: i16) {}
    fn bridge_off(&mut self) {}
}

/// The control period of a trace: the median time step, snapped to 1 ns so that a period
/// written as 1e-4 reads back as exactly 1e-4.
pub fn median_dt(trace: &Trace) -> Option<f64> {
    let m = crate::offline::median_spacing(trace.t_s.iter().copied())?;
    format!("{m:.9}").parse().ok().filter(|v: &f64| *v > 0.0)
}

/// Replays a trace. `dta_nm` is the controller's ΔT_a; `dt_s` overrides the trace's period.
pub fn replay(
    trace: &Trace,
    finger: &FingerFile,
    dta_nm: f64,
    dt_s: Option<f64>,
    method: crate::method::Method,
    settings: &MetaController,
) -> Result<Replay, String> {
    let mut warnings = vec![];
    let dt = match dt_s.or_else(|| median_dt(trace)) {
        Some(dt) => dt,
        None => return Err("the trace needs at least two rows with increasing t_s".into()),
    };
    let cfg = MetaController {
        estimator: Some(method),
        ..*settings
    }
    .apply(controller_config(finger, dt)?)
    .with_delta_ta(dta_nm);
    let mut ctl = Controller::new(cfg).map_err(|e| {
        format!("controller configuration for dt = {dt} s, ΔT_a = {dta_nm} N·m: {e:?}")
    })?;
    // Refused here, with the reason, rather than as an estimate error after the grasp.
    pts::Model::<grasp::EstReal>::new(&finger.finger)
        .map_err(|e| format!("finger on the firmware back end: {e}"))?;
    let raw = (0..trace.len())
        .all(|i| trace.encoder_count(i).is_some() && trace.current_code(i).is_some());
    if !raw {
        warnings.push(
            "no encoder_count/current_code columns: θa and T_a converted back to counts and \
             codes with the finger's drive constants (close to, not bit-exact with, the run)"
                .into(),
        );
    }
    let rest = cfg.drive.theta_a_rest_rad;
    let mut hw = TraceHw { count: 0, code: 0 };
    let mut rep = Replay {
        estimate: None,
        contact_t_s: None,
        contact: None,
        state: State::Init,
        states: Vec::with_capacity(trace.len()),
        dt_s: dt,
        raw,
        warnings,
    };
    let limits = Limits {
        max_ticks: trace.len() as u64,
        extra_ticks: None,
        timing: Timing::Immediate,
    };
    let mut obs = ReplayFeed {
        trace,
        finger,
        raw,
        rest,
        dt,
        drive: cfg.drive,
        rep: &mut rep,
        dither: 0.0,
        gaps: 0,
    };
    sim_board::run::run(&mut ctl, &mut hw, limits, &mut obs);
    let gaps = obs.gaps;
    if gaps > 0 {
        rep.warnings.push(format!(
            "{gaps} gap(s) longer than 1.5 control periods ({dt} s): the replay treats rows \
             as consecutive ticks"
        ));
    }
    rep.state = ctl.state();
    Ok(rep)
}

/// One contact found by the offline segmenter (`crate::offline`) in a trace our controller
/// did not produce, with the estimate `grasp::run_estimate_with` made from its request.
#[derive(Clone, Debug)]
pub struct SegmentedContact {
    /// Trace time of the contact (s).
    pub t_s: f64,
    /// θa,c (rad) and T_a,c (N·m) of the knee.
    pub theta_a_c: f64,
    /// T_a,c (N·m).
    pub ta_c: f64,
    /// Trace time of the settled end point (s).
    pub end_t_s: f64,
    /// The estimate, or the estimator's refusal.
    pub estimate: Result<EstimateResult, crate::sim::EstError>,
    /// The paper's two-point estimate on the same request (reported beside a path fit).
    pub two_point: Option<Result<EstimateResult, crate::sim::EstError>>,
    /// The drive identified from this contact's approach (path fit only).
    pub drive: Option<crate::offline::DriveId>,
    /// σ(k2,c) of a distal path-fit answer (m).
    pub sigma_k2_m: Option<f64>,
    /// σ(k2,c) of the path fit itself (m), before its widening for the contact friction the
    /// recording cannot show: what the block phases are weighted by, so that the answer
    /// does not depend on the friction prior.
    pub fit_sigma_k2_m: Option<f64>,
    /// Path fit: of the block phases the trace was segmented at, how many answered this
    /// contact on the distal phalanx (answered, phases).
    pub phases: Option<(u8, u8)>,
    /// Path fit with the drive identified: which samples it read (block phase 0's).
    pub path_reading: Option<PathReading>,
    /// Path fit: the effective inertia at the crank and the viscous term read on the contact
    /// path itself, where they replaced the approach's (block phase 0's; see
    /// `crate::offline::contact_inertia`).
    pub contact_dynamics: Option<crate::offline::ContactDynamics>,
}

/// Which samples the path fit read on a recording our controller did not make, and why.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PathReading {
    /// The samples as recorded, the drive's identified inertia removed by the fit and the
    /// bounce dropped by its envelope: no swing back that lies off the loading path (none at
    /// all, or one within the envelope without dry friction).
    AsRecorded,
    /// Only the rows that load the contact, with the drive's dynamics removed
    /// (`crate::offline::loading_path`): the swing back lies off the loading path.
    LoadingRows(LoadingReason),
}

/// Why the path fit read only the loading rows ([`PathReading::LoadingRows`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LoadingReason {
    /// The approach shows dry friction in the drive: its offset (N·m).
    DriveFriction {
        /// The drive's offset identified on the approach (N·m).
        offset_nm: f64,
    },
    /// The rows that swing back lie below those that load the contact (dry friction at the
    /// drive or at the object): the gap and its standard error (N·m).
    PathHysteresis {
        /// Mean torque of the loading rows above the swinging-back ones at the same θa (N·m).
        gap_nm: f64,
        /// Its standard error (N·m).
        sigma_nm: f64,
    },
    /// Without dry friction, the crank swung back: its damping parts the swing back from the
    /// loading rows.
    Swing,
}

impl PathReading {
    /// One line for people: what was read and why.
    pub fn describe(&self) -> String {
        match self {
            PathReading::AsRecorded => {
                "the samples as recorded (no swing back off the loading path)".into()
            }
            PathReading::LoadingRows(LoadingReason::DriveFriction { offset_nm }) => format!(
                "the loading rows only (dry friction in the drive: offset {offset_nm:.4} N·m on the approach)"
            ),
            PathReading::LoadingRows(LoadingReason::PathHysteresis { gap_nm, sigma_nm }) => {
                format!(
                    "the loading rows only (dry friction on the contact path: the swing back \
                     {gap_nm:.4} ± {sigma_nm:.1e} N·m below the loading)"
                )
            }
            PathReading::LoadingRows(LoadingReason::Swing) => {
                "the loading rows only (the crank swung back, without dry friction)".into()
            }
        }
    }

    /// The name in `--json` output: `as_recorded`, `loading_rows`.
    pub fn name(&self) -> &'static str {
        match self {
            PathReading::AsRecorded => "as_recorded",
            PathReading::LoadingRows(_) => "loading_rows",
        }
    }

    /// The reason's name in `--json` output, for the loading rows: `drive_friction`,
    /// `path_hysteresis`, `swing`.
    pub fn reason(&self) -> Option<&'static str> {
        match self {
            PathReading::AsRecorded => None,
            PathReading::LoadingRows(LoadingReason::DriveFriction { .. }) => Some("drive_friction"),
            PathReading::LoadingRows(LoadingReason::PathHysteresis { .. }) => {
                Some("path_hysteresis")
            }
            PathReading::LoadingRows(LoadingReason::Swing) => Some("swing"),
        }
    }
}

/// What the segmenter found: the contacts, and the error that ended the search (if any).
#[derive(Clone, Debug, Default)]
pub struct Segmented {
    /// Contacts in time order.
    pub contacts: Vec<SegmentedContact>,
    /// Why (more) contacts could not be used, as `kind: detail`.
    pub errors: Vec<(&'static str, String)>,
    /// Block length the trace was averaged into (s); the longest of its stretches'.
    pub block_s: f64,
    /// The gaps (first and last time, s) of more than [`GAP_SPLIT_S`] without rows at which
    /// the file was read as separate recordings.
    pub gaps_s: Vec<(f64, f64)>,
}

/// A stretch without rows longer than this (s) separates two recordings in one file (a logger
/// paused between grasps): each is segmented on its own. As long as the idle kept before a
/// grasp's first motion: nothing the segmentation reads spans it.
pub const GAP_SPLIT_S: f64 = 2.0;

/// Finds every contact of a recorded grasp with `crate::offline` (no controller replay: the
/// trace may come from any profile, sample rate or driver) and runs the firmware's estimator
/// on the request built for each. A file whose rows stop for more than [`GAP_SPLIT_S`] is read
/// as the recordings on either side of each such gap ([`Segmented::gaps_s`]); one that cannot
/// be segmented leaves its reason in [`Segmented::errors`] and the others are still read.
pub fn segment(
    trace: &Trace,
    finger: &FingerFile,
    method: crate::method::Method,
) -> Result<Segmented, crate::sim::EstError> {
    use crate::offline::TraceSample;
    let rows: Vec<TraceSample> = (0..trace.len())
        .map(|i| TraceSample {
            t_s: trace.t_s[i],
            theta_a_rad: trace.theta_a_rad[i],
            torque_nm: trace.torque_nm[i],
        })
        .collect();
    let mut stretches: Vec<&[TraceSample]> = Vec::new();
    let mut gaps_s = Vec::new();
    let mut from = 0;
    for (i, w) in rows.windows(2).enumerate() {
        if w[1].t_s - w[0].t_s > GAP_SPLIT_S {
            stretches.push(&rows[from..=i]);
            gaps_s.push((w[0].t_s, w[1].t_s));
            from = i + 1;
        }
    }
    stretches.push(&rows[from..]);
    if let [only] = stretches[..] {
        return segment_stretch(only, finger, method);
    }
    let mut out = Segmented {
        gaps_s,
        ..Segmented::default()
    };
    let (mut first_error, mut read_any) = (None, false);
    for stretch in stretches {
        let (t0, t1) = (
            stretch.first().map_or(0.0, |r| r.t_s),
            stretch.last().map_or(0.0, |r| r.t_s),
        );
        match segment_stretch(stretch, finger, method) {
            Ok(seg) => {
                out.contacts.extend(seg.contacts);
                out.errors
                    .extend(seg.errors.into_iter().map(|(kind, detail)| {
                        (
                            kind,
                            format!("the rows from t = {t0:.4} to {t1:.4} s: {detail}"),
                        )
                    }));
                out.block_s = out.block_s.max(seg.block_s);
                read_any = true;
            }
            Err(e) => {
                let detail = format!("the rows from t = {t0:.4} to {t1:.4} s: {e}");
                first_error.get_or_insert((e.kind, detail.clone()));
                out.errors.push(("stretch_unreadable", detail));
            }
        }
    }
    match first_error {
        // The first stretch's reason is the recording's: a reader matches on its kind.
        Some((kind, e)) if !read_any => Err(crate::sim::EstError::new(
            kind,
            &format!(
                "none of the {} stretches between gaps of more than {GAP_SPLIT_S} s could be \
                 segmented; first: {e}",
                out.gaps_s.len() + 1
            ),
        )),
        _ => Ok(out),
    }
}

/// [`segment`] on one stretch of rows without a gap of more than [`GAP_SPLIT_S`].
fn segment_stretch(
    rows: &[crate::offline::TraceSample],
    finger: &FingerFile,
    method: crate::method::Method,
) -> Result<Segmented, crate::sim::EstError> {
    // A long idle before the grasp (finger at rest, nothing to learn from) would lengthen
    // the blocks past the dynamics: start IDLE_KEEP_S before the crank first moves.
    const IDLE_KEEP_S: f64 = GAP_SPLIT_S;
    let start = crate::offline::first_moving_row(rows).map_or(0, |m| {
        let t_keep = rows[m].t_s - IDLE_KEEP_S;
        rows.partition_point(|r| r.t_s < t_keep)
    });
    let rows = rows.get(start..).unwrap_or_default().to_vec();
    // A recording in another angle frame would be read as a confident wrong answer (an encoder
    // zeroed at rest moves k2 by a fifth of l2 on the paper's finger): refused first.
    let m64 = pts::Model::<f64>::new(&finger.finger).map_err(|e| finger_error("finger", &e))?;
    crate::offline::check_rest_frame(&m64, &rows).map_err(segmenting_error)?;
    // A clipped step reads as a softer contact, or a proximal one: refused, with the level.
    crate::offline::check_saturation(&rows).map_err(segmenting_error)?;
    // A torque in another unit or sign finds no contact (no free motion to arm on, or none
    // that rises): the recording is then refused by what its approach shows instead. A
    // recording that is answered is never judged by this.
    let frame = crate::offline::check_torque_frame(&m64, &rows);
    let read = segment_in_frame(&rows, finger, method);
    match (frame, read) {
        (Err(e), Err(_)) => Err(segmenting_error(e)),
        (Err(e), Ok(s)) if s.contacts.is_empty() => Err(segmenting_error(e)),
        (_, read) => read,
    }
}

/// [`segment_stretch`] on rows in the finger's angle frame.
fn segment_in_frame(
    rows: &[crate::offline::TraceSample],
    finger: &FingerFile,
    method: crate::method::Method,
) -> Result<Segmented, crate::sim::EstError> {
    let rows = rows.to_vec();
    // The recording's encoder step: its smallest θa change between rows (of the rows as
    // recorded: interpolated ones below step by fractions of it).
    let quantum_rad = smallest_step(&rows);
    if method != crate::method::Method::Pathfit {
        return segment_rows(&rows, finger, method, quantum_rad);
    }
    // With fewer rows than phases in a block, the phases would average the same rows into
    // the same blocks: the rows (checked as recorded) are interpolated onto the phases' grid
    // first.
    let block_s =
        crate::offline::block_length(&offline_config(finger, method), &rows, SCRATCH_BLOCKS)
            .map_err(segmenting_error)?;
    let phase_s = block_s / BLOCK_PHASES as f64;
    let rows = interpolated(&rows, phase_s).unwrap_or(rows);
    let base = segment_rows(&rows, finger, method, quantum_rad)?;
    let t0 = rows.first().map_or(0.0, |r| r.t_s);
    let others: Vec<Segmented> = (1..BLOCK_PHASES)
        .filter_map(|j| {
            let shift = phase_s * j as f64;
            // The same rule for a row on the phase's start as for one on a block boundary.
            let start = t0 + shift - crate::offline::BOUNDARY_TOL * block_s;
            let from = rows.partition_point(|r| r.t_s < start);
            segment_rows(rows.get(from..)?, finger, method, quantum_rad).ok()
        })
        .collect();
    Ok(graded(combine_phases(base, &others), finger.finger.l2))
}

/// Each distal answer graded by the σ it now carries: the contact friction's widening and the
/// phases' spread move σ after the fit graded its own. Within [`NEAR_O2_SIGMAS`] σ of O2 it
/// is `proximal_or_near_o2` (a contact on the proximal phalanx next to O2 reads as one on the
/// distal next to it; `k2` stays the distal reading), else `low_signal` when σ is above a
/// twentieth of l2 (`l2_m`, m; [`grasp::estimate::path_fit_quality`]) whoever widened it. An
/// ambiguous answer stays ambiguous.
fn graded(mut seg: Segmented, l2_m: f64) -> Segmented {
    for c in seg.contacts.iter_mut() {
        if let (Ok(r), Some(sigma)) = (c.estimate.as_mut(), c.sigma_k2_m) {
            if r.located == grasp::Located::Distal && r.quality != grasp::Quality::Ambiguous {
                let k2_m = r.k2_um.map_or(f64::NAN, |k| f64::from(k) * 1e-6);
                if k2_m < NEAR_O2_SIGMAS * sigma {
                    r.located = grasp::Located::ProximalOrNearO2;
                    r.quality = grasp::Quality::Ambiguous;
                } else {
                    r.quality = grasp::estimate::path_fit_quality(sigma, l2_m);
                }
            }
        }
    }
    seg
}

/// A distal answer closer to O2 than this many of its σ is read as proximal or near O2
/// ([`graded`]).
const NEAR_O2_SIGMAS: f64 = 2.0;

/// The smallest θa change between consecutive rows (rad), 0 when θa never changes.
fn smallest_step(rows: &[crate::offline::TraceSample]) -> f64 {
    let q = rows
        .windows(2)
        .map(|w| (w[1].theta_a_rad - w[0].theta_a_rad).abs())
        .filter(|d| *d > 1e-12)
        .fold(f64::INFINITY, f64::min);
    if q.is_finite() {
        q
    } else {
        0.0
    }
}

/// The rows linearly interpolated onto a grid of `step_s` from the first row's time, where
/// the recording is sparser than that (its median row spacing above 1.25 `step_s`); `None`
/// where it is not. A block of a 250 Hz recording holds one row, and the block phases that
/// average where the rows fall about the contact would all see the same blocks (the engine
/// grid's `a_250_hz_recording_reads_alike_however_its_rows_fall`). Nothing is made up inside
/// a gap of more than twice the median spacing (rows the recording lost): grid times there
/// are left out.
fn interpolated(
    rows: &[crate::offline::TraceSample],
    step_s: f64,
) -> Option<Vec<crate::offline::TraceSample>> {
    let (first, last) = (rows.first()?, rows.last()?);
    let spacing = crate::offline::median_spacing(rows.iter().map(|r| r.t_s))?;
    if !(step_s > 0.0 && spacing > 1.25 * step_s) {
        return None;
    }
    let n = ((last.t_s - first.t_s) / step_s) as usize + 1;
    let mut out = Vec::with_capacity(n);
    let mut i = 0usize;
    for k in 0..n {
        let t = first.t_s + step_s * k as f64;
        while i + 2 < rows.len() && rows[i + 1].t_s <= t {
            i += 1;
        }
        let (a, b) = (rows[i], rows[(i + 1).min(rows.len() - 1)]);
        let dt = b.t_s - a.t_s;
        if dt > 2.0 * spacing && t > a.t_s {
            continue;
        }
        let w = if dt > 0.0 {
            ((t - a.t_s) / dt).clamp(0.0, 1.0)
        } else {
            1.0
        };
        out.push(crate::offline::TraceSample {
            t_s: t,
            theta_a_rad: a.theta_a_rad + w * (b.theta_a_rad - a.theta_a_rad),
            torque_nm: a.torque_nm + w * (b.torque_nm - a.torque_nm),
        });
    }
    Some(out)
}

/// Block phases the path fit runs at: the trace is averaged into blocks starting
/// `j/BLOCK_PHASES` of a block apart, and the answers combined ([`combine_phases`]).
const BLOCK_PHASES: usize = 4;

/// Contacts of two phases further apart than this are different contacts (s).
const PHASE_MATCH_S: f64 = 0.05;

/// One answer from the path fits at every block phase. Where the 4 ms blocks begin is an
/// arbitrary choice, yet the contact angle and the samples the fit keeps move with it (on the
/// sample traces k̂2 moves by a median 1.5 % of l2 between phases, up to 7 %). Each contact of
/// phase 0 (`base`) is matched with the nearest contact of the other phases; when at least
/// half of all phases answer it on the distal phalanx, k̂2 is their mean weighted by 1/σ² of
/// each fit's own σ (a phase whose blocks determine the path better counts more; the
/// widening for contact friction, the same prior on every phase, is left out so that it
/// moves σ and not k̂2) and σ² the same weighted mean of their σ² plus their spread about
/// k̂2 (the phases see the same data: their σ do not shrink as independent ones would);
/// else phase 0's answer is refused with another phase's reason. Other answers (proximal,
/// none) are phase 0's.
fn combine_phases(mut base: Segmented, others: &[Segmented]) -> Segmented {
    let total = 1 + others.len();
    for c in base.contacts.iter_mut() {
        let t = c.t_s;
        let matched: Vec<&SegmentedContact> = others
            .iter()
            .filter_map(|s| {
                s.contacts
                    .iter()
                    .filter(|o| (o.t_s - t).abs() <= PHASE_MATCH_S)
                    .min_by(|a, b| (a.t_s - t).abs().total_cmp(&(b.t_s - t).abs()))
            })
            .collect();
        // (the answer, k̂2 m, σ m, its weight 1/σ² of the fit's own σ)
        let distal = |x: &SegmentedContact| -> Option<(EstimateResult, f64, f64, f64)> {
            let r = x.estimate.as_ref().ok()?;
            let sigma = x.sigma_k2_m?;
            // A σ of 0 (a fit that states none) weighs as one of a micrometre.
            let weight = 1.0 / x.fit_sigma_k2_m.unwrap_or(sigma).max(1e-6).powi(2);
            (r.located == grasp::Located::Distal)
                .then_some(())
                .and(Some((*r, f64::from(r.k2_um?) * 1e-6, sigma, weight)))
        };
        let answers: Vec<(EstimateResult, f64, f64, f64)> = core::iter::once(&*c)
            .chain(matched.iter().copied())
            .filter_map(distal)
            .collect();
        let phase0_distal = distal(c).is_some();
        if !phase0_distal && answers.is_empty() {
            continue;
        }
        c.phases = Some((answers.len() as u8, total as u8));
        if 2 * answers.len() >= total {
            let total_weight = answers.iter().map(|a| a.3).sum::<f64>();
            let k2 = answers.iter().map(|a| a.3 * a.1).sum::<f64>() / total_weight;
            let var = answers
                .iter()
                .map(|a| a.3 * (a.2 * a.2 + (a.1 - k2) * (a.1 - k2)))
                .sum::<f64>()
                / total_weight;
            let sigma = var.sqrt();
            let mut r = answers[0].0;
            r.k2_um = Some(grasp::estimate::to_micro(k2));
            r.k2_sigma_um = Some(grasp::estimate::to_micro(sigma));
            c.estimate = Ok(r);
            c.sigma_k2_m = Some(sigma);
        } else if phase0_distal {
            let why = matched
                .iter()
                .find_map(|o| o.estimate.as_ref().err().cloned())
                .unwrap_or_else(|| {
                    crate::sim::EstError::new(
                        "phase_unstable",
                        &"fewer than half the block phases found this contact",
                    )
                });
            c.estimate = Err(why);
            c.sigma_k2_m = None;
        }
    }
    base
}

/// The most blocks a recording is averaged into (longer ones get longer blocks).
const SCRATCH_BLOCKS: usize = 1 << 16;

/// The segmenter's settings for this finger and method.
fn offline_config(
    finger: &FingerFile,
    method: crate::method::Method,
) -> crate::offline::OfflineConfig {
    crate::offline::OfflineConfig::DEFAULT
        .with_estimator(method.estimator())
        .with_encoder_count(finger.rad_per_count())
}

/// A recording the blocks cannot be made from, as the message `segment` returns.
fn segmenting_error(e: crate::offline::OfflineError) -> crate::sim::EstError {
    let detail = format!("segmenting the trace: {} ({e})", e.kind());
    crate::sim::EstError::new(e.kind(), &detail)
}

/// A finger file the model (or the firmware's back end) cannot be built from.
fn finger_error(what: &str, e: &dyn std::fmt::Display) -> crate::sim::EstError {
    crate::sim::EstError::new("finger_model", &format!("{what}: {e}"))
}

/// [`segment`] on rows already cut, at the block phase their first row sets; `quantum_rad` is
/// the recording's encoder step ([`smallest_step`] of the rows as recorded).
fn segment_rows(
    rows: &[crate::offline::TraceSample],
    finger: &FingerFile,
    method: crate::method::Method,
    quantum_rad: f64,
) -> Result<Segmented, crate::sim::EstError> {
    use crate::offline::{for_each_contact, make_blocks, Block};
    let m64 = pts::Model::<f64>::new(&finger.finger).map_err(|e| finger_error("finger", &e))?;
    let mfw = pts::Model::<grasp::EstReal>::new(&finger.finger)
        .map_err(|e| finger_error("finger on the firmware back end", &e))?;
    let cfg = offline_config(finger, method);
    // The file's drive as the firmware's estimate sees it (the two-point method reads none of it).
    let drive_fw = grasp::DriveConfig {
        inertia_kgm2: finger.drive.inertia_kgm2,
        backlash_rad: finger.drive.backlash_rad,
        priors: grasp::config::fit_priors(&finger.estimate),
        ..grasp::DriveConfig::DEFAULT
    };
    let mut scratch = vec![Block::default(); SCRATCH_BLOCKS];
    let (nb, block_s) = make_blocks(&m64, &cfg, rows, &mut scratch).map_err(segmenting_error)?;
    if method == crate::method::Method::Pathfit {
        dynamics_corrected_residual(&m64, &cfg, &mut scratch[..nb], block_s, finger, quantum_rad);
    }
    let blocks = &scratch[..nb];
    let mut out = Segmented {
        block_s,
        ..Segmented::default()
    };
    for_each_contact(
        &m64,
        &cfg,
        blocks,
        block_s,
        finger.rad_per_count(),
        |r| match r {
            Ok(seg) => {
                let fw = |req: &grasp::EstimateRequest| {
                    grasp::run_estimate_fw(&finger.finger, &drive_fw, &mfw, req)
                        .map_err(|e| crate::sim::EstError::new(e.kind(), &e))
                };
                let (mut t_s, mut theta_a_c, mut ta_c) =
                    (seg.contact_t_s, seg.theta_a_c_rad, seg.ta_c_nm);
                let (mut sigma_k2_m, mut fit_sigma_k2_m) = (None, None);
                let (mut path_reading, mut contact_dynamics) = (None, None);
                let (est, two_point, drive) = match method {
                    crate::method::Method::TwoPoint => (fw(&seg.request), None, None),
                    crate::method::Method::Pathfit => {
                        let fit = foreign_path_fit(&m64, &cfg, blocks, seg, finger, quantum_rad);
                        if let Some((_, c)) = &fit.drive {
                            (t_s, theta_a_c, ta_c) = *c;
                        }
                        path_reading = fit.reading;
                        contact_dynamics = fit.contact_dynamics;
                        fit_sigma_k2_m = fit.fit_sigma_m;
                        let mut tp = seg.request.clone();
                        tp.estimator = grasp::Estimator::TwoPoint;
                        let est = fit.estimate.map(|(r, s)| {
                            sigma_k2_m = s;
                            r
                        });
                        (est, Some(fw(&tp)), fit.drive.map(|f| f.0))
                    }
                };
                out.contacts.push(SegmentedContact {
                    t_s,
                    theta_a_c,
                    ta_c,
                    end_t_s: blocks
                        .get(seg.end.1.saturating_sub(1))
                        .map_or(f64::NAN, |b| b.t_s),
                    estimate: est,
                    two_point,
                    drive,
                    sigma_k2_m,
                    fit_sigma_k2_m,
                    phases: None,
                    path_reading,
                    contact_dynamics,
                });
            }
            Err(e) => out.errors.push((e.kind(), e.to_string())),
        },
    );
    Ok(out)
}

/// The contact detection's residual with the drive's dynamics taken out. A drive with little
/// friction rings in free motion (the crank oscillates on the links' springs, period
/// 2π·√(J/K)), and where the ringing nearly stalls the crank the static residual
/// T_a − T_free(θa) rises as a contact's would (measured on the engine grid: knees 60-85 mrad
/// before the contact). The drive is identified (`crate::offline::identify_drive`) on the
/// approach up to the first static detection — free motion whether that detection is the
/// contact or the ringing — and each block's residual becomes
/// T_a − T_free(θa) − viscous·θ̇a − inertia·θ̈a, which is noise in free motion whatever the
/// crank's speed and rises at the contact only, with θ̇a and θ̈a from a local quartic in time
/// (`crate::offline::drive::poly_speed_accel`), which follows the ringing where a second
/// difference of the same noise reads it several percent low. The torques themselves are left
/// as recorded: the path fit carries the identified inertia on its own.
fn dynamics_corrected_residual(
    m64: &pts::Model<f64>,
    cfg: &crate::offline::OfflineConfig,
    blocks: &mut [crate::offline::Block],
    block_s: f64,
    finger: &FingerFile,
    quantum_rad: f64,
) {
    use crate::offline::{find_contact, identify_drive_dynamics, DrivePrior};
    let q = finger.rad_per_count();
    let Ok(seg) = find_contact(m64, cfg, blocks, block_s, q, 0) else {
        return;
    };
    let prior = DrivePrior {
        inertia_kgm2: finger.drive.inertia_kgm2,
        sigma_inertia_kgm2: finger.drive.inertia_kgm2,
    };
    let Some((inertia_kgm2, viscous_nm_s_per_rad)) =
        identify_drive_dynamics(m64, blocks, 0, seg.knee.saturating_sub(4), q, &prior)
    else {
        return;
    };
    // The encoder's quantisation (`quantum_rad`, the recording's smallest θa step) on
    // inertia·θ̈a held to a quarter of the detection threshold.
    let half = quartic_half_width(
        inertia_kgm2,
        quantum_rad,
        block_s,
        0.25 * cfg.detect_excess_nm,
    );
    let corr: Vec<f64> = (0..blocks.len())
        .map(|k| {
            crate::offline::drive::poly_speed_accel(blocks, k, half)
                .map(|(w, acc)| viscous_nm_s_per_rad * w + inertia_kgm2 * acc)
                .unwrap_or(0.0)
        })
        .collect();
    for (b, c) in blocks.iter_mut().zip(corr) {
        b.resid_nm -= c;
    }
}

/// The path fit's envelope tolerance (rad) with the drive's inertia identified on this very
/// recording: its correction J·θ̈a leaves the oscillation on the contact (a heavy, lightly
/// damped drive swings several mrad about the path for the whole hold) on the path, so the
/// envelope only has to drop a bounce off the object. The default 2 mrad stands for an
/// inertia the fit is only told.
const IDENTIFIED_ENVELOPE_TOL_RAD: f64 = 0.02;

/// σ(k2,c) of a distal answer widened by the contact friction the recording cannot show.
/// Friction at the object resists the contact's outward slide while loading and reads as a
/// contact further out (MODEL.md §7); one loading path cannot tell µ from k2,c (χ² is flat
/// over µ), and the fit assumes µ = 0. So the same request is fitted again with the finger
/// file's largest friction coefficient (`contact.mu_max`, [`pts::config::Contact`]): over a µ
/// anywhere in 0..µmax the true k2,c lies between the two answers, and the spread δ between
/// them enters σ as a uniform one, δ/√3 from the end the answer reports. A request the second
/// fit refuses keeps its σ, and so does a finger whose pads hold no friction (µmax = 0).
fn widen_for_contact_friction(
    finger: &FingerFile,
    pcfg: &pathfit::PathFitConfig,
    dt: f64,
    req: &grasp::EstimateRequest,
    contact: (f64, f64, f64),
    mut r: EstimateResult,
    sigma: Option<f64>,
) -> (EstimateResult, Option<f64>) {
    let (Some(s0), Some(k0), grasp::Located::Distal) = (sigma, r.k2_um, r.located) else {
        return (r, sigma);
    };
    if finger.contact.mu_max <= 0.0 {
        return (r, sigma);
    }
    let cfg_mu = pathfit::PathFitConfig {
        contact_mu: finger.contact.mu_max,
        ..*pcfg
    };
    let k_mu = pathfit::q::PathTable::new(&finger.finger, &cfg_mu, dt)
        .ok()
        .and_then(|t| crate::offline::path_fit_with(&t, req, contact.0, contact.1).ok())
        .filter(|(x, _)| x.located == grasp::Located::Distal)
        .and_then(|(x, _)| x.k2_um);
    let Some(k_mu) = k_mu else {
        return (r, sigma);
    };
    let delta = f64::from(k0 - k_mu) * 1e-6;
    let s = (s0 * s0 + delta * delta / 3.0).sqrt();
    r.k2_sigma_um = Some(grasp::estimate::to_micro(s));
    (r, Some(s))
}

/// Why a contact whose torque step came with it cannot be read, or `None`: more than half of
/// ΔT_a (the request's end torque over T_a,c) reached within [`STEP_AT_CONTACT_S`] of the
/// contact (`contact`: θa,c rad, T_a,c N·m, t s; either side, as the contact may be found
/// late). Under a torque held constant from the contact on, the contact path's own inertia
/// cannot be read (its torque never changes), so the approach's stands, which carries the
/// finger links' share; and the contact's kink hides in the step's, so the contact is found
/// late. Both read the contact further out, at a σ that does not know it (on the engine's
/// light drive 3–4 mrad late and +5 to +9 % of l2 at σ 1–3 %). The caller keeps a proximal
/// answer, which that bias only moves away from.
fn step_at_contact(
    blocks: &[crate::offline::Block],
    req: &grasp::EstimateRequest,
    (_, ta_c, t_c): (f64, f64, f64),
) -> Option<String> {
    let dta = f64::from(req.end.torque_unm) * 1e-6 - ta_c;
    let rise = blocks
        .iter()
        .filter(|b| (b.t_s - t_c).abs() <= STEP_AT_CONTACT_S)
        .map(|b| b.torque_nm - ta_c)
        .fold(f64::NEG_INFINITY, f64::max);
    (dta > 0.0 && rise > 0.5 * dta).then(|| {
        format!(
            "the torque rose by {rise:.3} N·m within {:.0} ms of the contact at t = {t_c:.4} s, \
             more than half its step of {dta:.3} N·m: a step that comes with the contact hides \
             the contact and the inertia on it; hold the torque 30 ms after the contact before \
             the step (a step that late is read), or ramp it",
            STEP_AT_CONTACT_S * 1e3
        )
    })
}

/// How soon after the contact (s) a torque step makes the contact unreadable
/// ([`step_at_contact`]): the engine's steps at the contact are refused, its steps 30 ms after
/// it and its 0.05 s ramps at it (a fifth of the step within this time) are read.
const STEP_AT_CONTACT_S: f64 = 0.01;

/// How far the crank must swing back after the contact (rad) before the path of a drive
/// without dry friction is rebuilt from its loading rows (`crate::offline::loading_path`):
/// any distance. The damping on the contact (the drive's and the object's,
/// [`crate::offline::contact_inertia`]) resists the motion both ways, so the rows that swing
/// back lie below the quasi-static path by b·θ̇a and the loading rows above it; read together
/// they bend the path with the ring's decay, while the loading rows with b·θ̇a removed lie on
/// it.
const LOADING_MIN_SWING_RAD: f64 = 0.0;

/// An approach offset (N·m, [`crate::offline::DriveId::offset_nm`]) above which the drive has
/// dry friction, and the path is rebuilt from the loading rows on any swing back: a crank that
/// swings back or sticks leaves samples off the loading path by up to twice the friction, on
/// either side, which the envelope does not sort out. A current sensor's offset or gain error
/// alone stays below it. The engine grids and the sample recordings answer the same for any
/// value from 0.005 to 0.015 N·m.
const DRY_FRICTION_MIN_NM: f64 = 0.01;

/// A hysteresis of the contact path (N·m, [`crate::offline::path_hysteresis`]) above which the
/// path has dry friction (at the drive or at the object), and is rebuilt from the loading rows
/// on any swing back: the gap between loading and swinging back that a dry friction of
/// [`DRY_FRICTION_MIN_NM`] opens (twice it). Counted only where it also exceeds three of its
/// standard errors.
const HYSTERESIS_MIN_NM: f64 = 2.0 * DRY_FRICTION_MIN_NM;

/// The largest relative standard error of the contact path's own inertia
/// ([`crate::offline::contact_inertia`]) at which it replaces the approach's, which it must
/// also differ from by more than three standard errors: where the oscillation on the contact
/// determines it this well and shows the approach's wrong, it is the better of the two (the
/// approach's misses the finger links' change of share, several percent on a light drive).
const CONTACT_INERTIA_MAX_REL_SIGMA: f64 = 0.03;

/// How far above the contact angle found (rad) the contact path's own inertia is read: the
/// contact angle's usual uncertainty (the default prior σ of θa,c, `[estimate]
/// contact_angle_sigma_rad`), so that a swing back off the object, which follows the free
/// motion, stays out.
const CONTACT_INERTIA_MARGIN_RAD: f64 = 3e-3;

/// The fit's envelope tolerance (rad) on a loading path rebuilt by
/// `crate::offline::loading_path`: its samples are in order of θa, with the inertia already
/// removed, so there is no overshoot left to drop.
const LOADING_ENVELOPE_TOL_RAD: f64 = 1.0;

/// Half-width (blocks) of the local quartic for θ̇a and θ̈a (the detection's residual, the
/// loading path): the shortest (the most faithful to an oscillation) that keeps the encoder's
/// quantisation noise on inertia·θ̈a (a uniform error of a quantum `quantum_rad` on θa,
/// standard deviation q/√12) within `noise_nm`; at most [`MAX_QUARTIC_HALF_WIDTH`].
fn quartic_half_width(inertia_kgm2: f64, quantum_rad: f64, block_s: f64, noise_nm: f64) -> usize {
    crate::offline::drive::poly_half_width(
        block_s,
        quantum_rad / 12f64.sqrt(),
        noise_nm / inertia_kgm2,
        MAX_QUARTIC_HALF_WIDTH,
    )
}

/// The widest quartic (blocks): ±48 ms at 4 ms, a half period of a 10 Hz ring on the contact,
/// which a quartic still follows to a percent.
const MAX_QUARTIC_HALF_WIDTH: usize = 12;

/// How [`foreign_path_fit`] reads a contact path once the drive is identified.
#[derive(Clone, Copy)]
struct PathJudgement {
    /// Half-width (blocks) of the local quartic for θ̇a and θ̈a.
    half_width: usize,
    /// The approach's viscous term (N·m·s/rad).
    viscous_nm_s_per_rad: f64,
    /// Why the loading rows would be read alone (`Swing`: no dry friction seen).
    reason: LoadingReason,
    /// The contact path's own inertia and viscous term, where they replace the approach's.
    contact_dynamics: Option<crate::offline::ContactDynamics>,
}

/// What [`foreign_path_fit`] found on one contact.
struct ForeignFit {
    /// The estimate with its σ(k2,c) (m), or the refusal.
    estimate: Result<(EstimateResult, Option<f64>), crate::sim::EstError>,
    /// The drive identified on the approach, with the contact point used (t s, θa,c rad,
    /// T_a,c N·m).
    drive: Option<(crate::offline::DriveId, (f64, f64, f64))>,
    /// Which samples the fit read (with the drive identified).
    reading: Option<PathReading>,
    /// The contact path's own inertia and viscous term, where the fit used them.
    contact_dynamics: Option<crate::offline::ContactDynamics>,
    /// σ(k2,c) of the fit (m) before the widening for contact friction.
    fit_sigma_m: Option<f64>,
}

/// The path fit on a recording our controller did not make: the drive's inertia, viscous
/// term and friction offset identified from this contact's approach
/// (`crate::offline::identify_drive`, the finger file's inertia as the prior), the inertia
/// read again on the contact path where that rings without dry friction and shows the
/// approach's wrong (`crate::offline::contact_inertia`), the contact point on the
/// dynamics-corrected residual (`crate::offline::refine_contact`), then the
/// firmware's integer path fit with that inertia and the finger file's backlash. Without an
/// identification (too short an approach) the controller's defaults.
fn foreign_path_fit(
    m64: &pts::Model<f64>,
    cfg: &crate::offline::OfflineConfig,
    blocks: &[crate::offline::Block],
    seg: &crate::offline::Segment,
    finger: &FingerFile,
    quantum_rad: f64,
) -> ForeignFit {
    use crate::offline::{identify_drive, path_fit_with, refine_contact, DriveId, DrivePrior};
    let q = finger.rad_per_count();
    let prior = DrivePrior {
        inertia_kgm2: finger.drive.inertia_kgm2,
        sigma_inertia_kgm2: finger.drive.inertia_kgm2,
    };
    let err = |e: grasp::EstimateError| crate::sim::EstError::new(e.kind(), &e);
    let id = identify_drive(
        m64,
        blocks,
        0,
        seg.knee.saturating_sub(4),
        q,
        quantum_rad,
        &prior,
    );
    // With the drive identified: does the path show dry friction (the approach's, or the
    // hysteresis of the contact path, the drive's or the object's, which no approach sees)?
    // Without, the oscillation on the contact carries the inertia the fit removes: the
    // contact path's own ([`crate::offline::contact_inertia`]) where it determines it.
    let block_s = f64::from(seg.request.dt_ns) * 1e-9;
    let judged = id.as_ref().map(|d| {
        let half = quartic_half_width(d.inertia_kgm2, quantum_rad, block_s, cfg.detect_excess_nm);
        let drive = (d.inertia_kgm2, d.viscous_nm_s_per_rad);
        let reason = if d.offset_nm > DRY_FRICTION_MIN_NM {
            LoadingReason::DriveFriction {
                offset_nm: d.offset_nm,
            }
        } else {
            match crate::offline::path_hysteresis(blocks, seg.knee, seg.end.1, drive, half) {
                Some((gap_nm, sigma_nm))
                    if gap_nm > HYSTERESIS_MIN_NM && gap_nm > 3.0 * sigma_nm =>
                {
                    LoadingReason::PathHysteresis { gap_nm, sigma_nm }
                }
                _ => LoadingReason::Swing,
            }
        };
        let on_contact = match reason {
            LoadingReason::Swing => {
                let from = seg.theta_a_c_rad + CONTACT_INERTIA_MARGIN_RAD;
                crate::offline::contact_inertia(blocks, seg.knee, seg.end.1, from, half).filter(
                    |c| {
                        let (j, s) = (c.inertia_kgm2, c.sigma_inertia_kgm2);
                        j > 0.0
                            && s <= CONTACT_INERTIA_MAX_REL_SIGMA * j
                            && (j - d.inertia_kgm2).abs() > 3.0 * s.hypot(d.sigma_inertia_kgm2)
                    },
                )
            }
            _ => None,
        };
        PathJudgement {
            half_width: half,
            viscous_nm_s_per_rad: d.viscous_nm_s_per_rad,
            reason,
            contact_dynamics: on_contact,
        }
    });
    let contact_dynamics = judged.and_then(|j| j.contact_dynamics);
    // The contact point's hinge reads the impact through the inertia on the contact.
    let id_on_contact = id.map(|d| DriveId {
        inertia_kgm2: contact_dynamics.map_or(d.inertia_kgm2, |c| c.inertia_kgm2),
        ..d
    });
    let (inertia, contact) = match id_on_contact {
        Some(id) => (
            id.inertia_kgm2,
            refine_contact(m64, cfg, blocks, seg, &id, q).unwrap_or((
                seg.theta_a_c_rad,
                seg.ta_c_nm,
                seg.contact_t_s,
            )),
        ),
        None => (
            finger.drive.inertia_kgm2,
            (seg.theta_a_c_rad, seg.ta_c_nm, seg.contact_t_s),
        ),
    };
    // A proximal answer stands under a step at the contact: the approach's inertia, which the
    // step leaves in place, reads the contact stiffer, further from the proximal phalanx.
    let step_refusal = step_at_contact(blocks, &seg.request, contact)
        .map(|why| crate::sim::EstError::new("step_at_contact", &why));
    // A finger that settles behind the angle of its first contact has left the object (a
    // rigid object touched at θa,c holds the finger ahead of that angle), or the contact was
    // found late (a heavy drive's impact carries the finger far past it). Whatever the rows
    // before the end fit, they are no loading path to a held contact.
    let end_rad = f64::from(seg.request.end.theta_a_urad) * 1e-6;
    if end_rad <= contact.0 {
        let why = format!(
            "the finger settled at θa = {end_rad:.4} rad, behind the contact found at {:.4} rad: \
             it left the object, or the contact lies earlier than the recording shows",
            contact.0
        );
        // A step at the contact is the likelier reason, and says what to do instead.
        let refusal =
            step_refusal.unwrap_or_else(|| crate::sim::EstError::new("end_behind_contact", &why));
        return ForeignFit {
            estimate: Err(refusal),
            drive: id.map(|i| (i, (contact.2, contact.0, contact.1))),
            reading: None,
            contact_dynamics,
            fit_sigma_m: None,
        };
    }
    let pcfg = pathfit::PathFitConfig {
        inertia_kgm2: inertia,
        encoder_lead_rad: 0.5 * finger.drive.backlash_rad,
        envelope_tol_rad: if id.is_some() {
            IDENTIFIED_ENVELOPE_TOL_RAD
        } else {
            pathfit::PathFitConfig::DEFAULT.envelope_tol_rad
        },
        ..pathfit::PathFitConfig::DEFAULT.with_priors(grasp::config::fit_priors(&finger.estimate))
    };
    // With dry friction, or with the crank swinging back at all, the path is the loading rows
    // with its dynamics removed here (`crate::offline::loading_path`; the contact path's own
    // inertia and damping where they were read there), and the fit is told neither inertia
    // nor envelope.
    // Dry friction needs no swing: its stuck rows are off the loading path either way (and a
    // swing of "more than zero" would be decided by how the block means round).
    let (loading, reading) = judged.map_or((None, None), |j| {
        let min_swing = match j.reason {
            LoadingReason::Swing => LOADING_MIN_SWING_RAD,
            _ => f64::NEG_INFINITY,
        };
        let req = crate::offline::loading_path(
            &seg.request,
            blocks,
            seg.knee,
            seg.end.1,
            (
                inertia,
                contact_dynamics
                    .map_or(j.viscous_nm_s_per_rad, |c| c.viscous_nm_s_per_rad.max(0.0)),
            ),
            j.half_width,
            min_swing,
        );
        let reading = if req.is_some() {
            PathReading::LoadingRows(j.reason)
        } else {
            PathReading::AsRecorded
        };
        (req, Some(reading))
    });
    let (pcfg, req) = match loading {
        Some(req) => (
            pathfit::PathFitConfig {
                inertia_kgm2: 0.0,
                envelope_tol_rad: LOADING_ENVELOPE_TOL_RAD,
                ..pcfg
            },
            req,
        ),
        None => (pcfg, seg.request.clone()),
    };
    let res = pathfit::q::PathTable::new(&finger.finger, &pcfg, block_s)
        .map_err(|e| err(grasp::EstimateError::Model(e)))
        .and_then(|table| {
            path_fit_with(&table, &req, contact.0, contact.1)
                .map_err(|e| err(grasp::EstimateError::PathFit(e)))
        });
    let res = match (res, step_refusal) {
        (Ok((r, s)), _) if r.located == grasp::Located::Proximal => Ok((r, s)),
        (_, Some(refusal)) => Err(refusal),
        (res, None) => res,
    };
    let fit_sigma_m = res.as_ref().ok().and_then(|(_, sigma)| *sigma);
    let res = res.map(|(r, sigma)| {
        widen_for_contact_friction(finger, &pcfg, block_s, &req, contact, r, sigma)
    });
    ForeignFit {
        estimate: res,
        drive: id.map(|i| (i, (contact.2, contact.0, contact.1))),
        reading,
        contact_dynamics,
        fit_sigma_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn contact(t_s: f64, k2_mm: Option<f64>, sigma_mm: f64) -> SegmentedContact {
        let estimate = match k2_mm {
            Some(k) => Ok(EstimateResult {
                located: grasp::Located::Distal,
                k2_um: Some((k * 1e3) as i32),
                k2_sigma_um: Some((sigma_mm * 1e3) as i32),
                radius_um: None,
                two_point_k2_um: None,
                kc_hat_unm_per_rad: 0,
                kc_proximal_unm_per_rad: 0,
                kc_tip_unm_per_rad: 0,
                delta_ta_unm: 0,
                delta_theta_a_urad: 0,
                theta_a_c_urad: 0,
                ta_c_unm: 0,
                quality: grasp::Quality::Good,
            }),
            None => Err(crate::sim::EstError::new("not_determined", &"σ too large")),
        };
        SegmentedContact {
            t_s,
            theta_a_c: 0.0,
            ta_c: 0.0,
            end_t_s: t_s + 0.5,
            estimate,
            two_point: None,
            drive: None,
            sigma_k2_m: k2_mm.map(|_| sigma_mm * 1e-3),
            fit_sigma_k2_m: k2_mm.map(|_| sigma_mm * 1e-3),
            phases: None,
            path_reading: None,
            contact_dynamics: None,
        }
    }

    fn phase(c: SegmentedContact) -> Segmented {
        Segmented {
            contacts: vec![c],
            ..Segmented::default()
        }
    }

    #[test]
    fn sparse_rows_are_interpolated_onto_the_phase_grid() {
        use crate::offline::TraceSample;
        let row = |t: f64| TraceSample {
            t_s: t,
            theta_a_rad: -0.3 + 0.5 * t,
            torque_nm: 0.2 + 2.0 * t,
        };
        // 250 Hz onto 1 ms: every grid time, exact on a line, the last row kept.
        let sparse: Vec<TraceSample> = (0..6).map(|i| row(0.004 * i as f64)).collect();
        let fine = interpolated(&sparse, 0.001).expect("sparser than the grid");
        assert_eq!(fine.len(), 21);
        for (k, r) in fine.iter().enumerate() {
            let want = row(0.001 * k as f64);
            assert!((r.t_s - want.t_s).abs() < 1e-12, "{k}");
            assert!((r.theta_a_rad - want.theta_a_rad).abs() < 1e-12, "{k}");
            assert!((r.torque_nm - want.torque_nm).abs() < 1e-12, "{k}");
        }
        // A row repeated at one time takes the later value, and nothing panics.
        let mut dup = sparse.clone();
        dup.insert(
            2,
            TraceSample {
                torque_nm: 9.0,
                ..sparse[2]
            },
        );
        let fine = interpolated(&dup, 0.001).expect("sparser than the grid");
        assert!((fine[8].torque_nm - row(0.008).torque_nm).abs() < 1e-12);
        // A lost stretch (12 ms between two rows) gets no rows made up inside it.
        let mut lost = sparse.clone();
        lost.extend((0..6).map(|i| row(0.032 + 0.004 * i as f64)));
        let fine = interpolated(&lost, 0.001).expect("sparser than the grid");
        assert!(fine.iter().all(|r| !(r.t_s > 0.0201 && r.t_s < 0.0319)));
        assert_eq!(fine.len(), 21 + 21);
        // Rows as dense as the grid, or a single row, stay as they are.
        let dense: Vec<TraceSample> = (0..20).map(|i| row(0.001 * i as f64)).collect();
        assert!(interpolated(&dense, 0.001).is_none());
        assert!(interpolated(&sparse[..1], 0.001).is_none());
        assert!(interpolated(&[], 0.001).is_none());
    }

    #[test]
    fn phases_answering_are_averaged_with_their_spread_in_sigma() {
        let base = phase(contact(0.9, Some(40.0), 3.0));
        let others = [
            phase(contact(0.901, Some(44.0), 3.0)),
            phase(contact(0.899, None, 0.0)),
            // Another contact, 0.3 s later: not this one's phase.
            phase(contact(1.2, Some(10.0), 1.0)),
        ];
        let out = combine_phases(base, &others);
        let c = &out.contacts[0];
        assert_eq!(c.phases, Some((2, 4)));
        let r = c.estimate.as_ref().unwrap();
        assert_eq!(r.k2_um, Some(42_000));
        // σ² = mean σ² (9 mm²) + spread (4 mm²).
        let s = c.sigma_k2_m.unwrap();
        assert!((s - 13f64.sqrt() * 1e-3).abs() < 1e-9, "{s}");
        assert_eq!(r.k2_sigma_um, Some(grasp::estimate::to_micro(s)));
    }

    /// A phase whose fit states a smaller σ counts more: 40 mm at 2 mm and 46 mm at 4 mm
    /// read (40/4 + 46/16) / (1/4 + 1/16) = 41.2 mm, σ² = (0.25 (4 + 1.44) + 0.0625 (16 +
    /// 23.04)) / 0.3125 = 12.16 mm². The σ widened for contact friction does not weigh: with
    /// the fits' own σ alike, the mean is the plain one whatever the widened σ say.
    #[test]
    fn phases_weigh_by_their_fit_s_own_sigma() {
        let out = combine_phases(
            phase(contact(0.9, Some(40.0), 2.0)),
            &[phase(contact(0.9, Some(46.0), 4.0))],
        );
        let c = &out.contacts[0];
        assert_eq!(c.estimate.as_ref().unwrap().k2_um, Some(41_200));
        let s = c.sigma_k2_m.unwrap();
        assert!((s - 12.16f64.sqrt() * 1e-3).abs() < 1e-9, "{s}");
        let widened = |k2_mm: f64, sigma_mm: f64| {
            let mut x = contact(0.9, Some(k2_mm), sigma_mm);
            x.fit_sigma_k2_m = Some(2e-3);
            x
        };
        let out = combine_phases(phase(widened(40.0, 2.0)), &[phase(widened(46.0, 6.0))]);
        let c = &out.contacts[0];
        assert_eq!(c.estimate.as_ref().unwrap().k2_um, Some(43_000));
    }

    /// The grade follows the σ an answer reports, not the one its fit had: on l2 = 75 mm the
    /// line is 3.75 mm. Two good phases whose spread widens σ past it read `low_signal`; a fit
    /// graded `low_signal` whose combined σ lies under it reads `good`; an ambiguous answer
    /// and a refusal stay as they are; an answer within two σ of O2 is ambiguous.
    #[test]
    fn answers_are_graded_by_the_sigma_they_report() {
        let l2 = 0.075;
        let quality = |s: &Segmented| s.contacts[0].estimate.as_ref().unwrap().quality;
        let out = graded(
            combine_phases(
                phase(contact(0.9, Some(30.0), 2.0)),
                &[phase(contact(0.9, Some(38.0), 2.0))],
            ),
            l2,
        );
        assert!(out.contacts[0].sigma_k2_m.unwrap() > 0.05 * l2);
        assert_eq!(quality(&out), grasp::Quality::LowSignal);
        let mut low = contact(0.9, Some(30.0), 3.7);
        if let Ok(r) = low.estimate.as_mut() {
            r.quality = grasp::Quality::LowSignal;
        }
        assert_eq!(quality(&graded(phase(low), l2)), grasp::Quality::Good);
        let mut ambiguous = contact(0.9, Some(30.0), 9.0);
        if let Ok(r) = ambiguous.estimate.as_mut() {
            r.quality = grasp::Quality::Ambiguous;
        }
        assert_eq!(
            quality(&graded(phase(ambiguous), l2)),
            grasp::Quality::Ambiguous
        );
        let refused = graded(phase(contact(0.9, None, 0.0)), l2);
        assert!(refused.contacts[0].estimate.is_err());
        // 3 mm from O2 at σ 2 mm: a proximal contact next to O2 reads so too.
        let near = graded(phase(contact(0.9, Some(3.0), 2.0)), l2);
        let r = near.contacts[0].estimate.as_ref().unwrap();
        assert_eq!(r.located, grasp::Located::ProximalOrNearO2);
        assert_eq!(r.quality, grasp::Quality::Ambiguous);
        assert_eq!(r.k2_um, Some(3000));
        let clear = graded(phase(contact(0.9, Some(5.0), 2.0)), l2);
        let r = clear.contacts[0].estimate.as_ref().unwrap();
        assert_eq!(r.located, grasp::Located::Distal);
    }

    #[test]
    fn fewer_than_half_answering_is_a_refusal_with_a_phase_reason() {
        let base = phase(contact(0.9, Some(40.0), 3.0));
        let others = [
            phase(contact(0.9, None, 0.0)),
            phase(contact(0.9, None, 0.0)),
            Segmented::default(),
        ];
        let out = combine_phases(base, &others);
        let c = &out.contacts[0];
        assert_eq!(c.phases, Some((1, 4)));
        assert_eq!(c.estimate.as_ref().unwrap_err().kind, "not_determined");
        assert_eq!(c.sigma_k2_m, None);
        // Phase 0 refused but two others answered: answered from them.
        let out = combine_phases(
            phase(contact(0.9, None, 0.0)),
            &[
                phase(contact(0.9, Some(30.0), 2.0)),
                phase(contact(0.9, Some(30.0), 2.0)),
            ],
        );
        let c = &out.contacts[0];
        assert_eq!(c.phases, Some((2, 3)));
        assert_eq!(c.estimate.as_ref().unwrap().k2_um, Some(30_000));
    }

    /// A `# pts-sim` line says which controller made the recording: read back as written,
    /// and what an older line leaves out as the controller of its time (seated, a 1 N·m/s
    /// ramp), not as today's default.
    #[test]
    fn the_pts_sim_line_keeps_the_controller_and_reads_old_lines_as_seated() {
        let meta = TraceMeta {
            dta_nm: 0.8,
            dt_s: 2e-4,
            drive: None,
            controller: MetaController {
                step_ramp_nm_per_s: Some(4.0),
                seating: Some(false),
                ..MetaController::default()
            },
        };
        let back = TraceMeta::find(&meta.line()).expect("its own line");
        assert_eq!(back.controller.seating, Some(false));
        assert_eq!(back.controller.step_ramp_nm_per_s, Some(4.0));
        let old = TraceMeta::find("# pts-sim dta_nm=0.8 dt_s=0.0002").expect("an old line");
        assert_eq!(old.controller.seating, Some(true));
        assert_eq!(old.controller.step_ramp_nm_per_s, Some(1.0));
        let c = old.controller.apply(ControllerConfig::DEFAULT);
        assert!(c.seating);
        assert_eq!(c.step_shape, grasp::StepShape::Ramp(1.0));
        let old_step = TraceMeta::find("# pts-sim dta_nm=0.8 dt_s=0.0002 step_ramp_nm_per_s=0")
            .expect("an old line with a step");
        assert_eq!(old_step.controller.step_ramp_nm_per_s, Some(0.0));
        // `pts sim --no-seating` before the ramp was written: unseated, at the old default.
        let old_unseated = TraceMeta::find("# pts-sim dta_nm=0.8 dt_s=0.0002 seating=0")
            .expect("an old unseated line");
        assert_eq!(old_unseated.controller.seating, Some(false));
        assert_eq!(old_unseated.controller.step_ramp_nm_per_s, Some(1.0));
    }
}
