//! The host ↔ firmware protocol of the finger's motor controller, used by both sides.
//!
//! Every message is a postcard body behind a one-byte protocol version and followed by a
//! CRC-16 (little endian), the whole COBS-encoded and terminated by a zero byte ([`frame`]).
//! The host sends [`Request`]s (an id it chooses and a [`Command`]); the device answers each
//! with a [`DeviceMsg::Reply`] carrying the same id, and sends events, contact estimates and
//! telemetry samples unasked as they happen. The first exchange is [`Command::Hello`]: both
//! sides then know they speak the same [`VERSION`].
//!
//! Units are in the names: µrad, µN·m, µm for the integers the controller produces, SI units
//! for the parameters a user sets.
#![no_std]

pub mod frame;
pub mod log;
mod settings;

pub use frame::{encode, Decoder, EncodeError, FrameError, Message, MAX_FRAME, MAX_PAYLOAD};
pub use settings::{Settings, SettingsError};

use serde::{Deserialize, Serialize};

/// Protocol version: the first byte of every frame and the value of the hello exchange.
/// Raised whenever a message's encoding changes.
pub const VERSION: u8 = 4;

/// A scene name of the simulated build (the plant's scene catalogue), at most 24 bytes.
pub type SceneName = heapless::String<24>;

/// A short text (firmware name, board name), at most 24 bytes.
pub type Name = heapless::String<24>;

/// One host request: an id the host chooses (echoed in the reply) and the command.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Request {
    /// Correlates the reply with this request.
    pub id: u16,
    /// What to do.
    pub cmd: Command,
}

/// What the host asks of the device.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Command {
    /// Version exchange: the host's protocol version. Answered by [`Reply::Hello`], or by
    /// [`Error::VersionMismatch`].
    Hello {
        /// The host's [`VERSION`].
        version: u8,
    },
    /// The device's state, settings and counters ([`Reply::Status`]).
    Status,
    /// One parameter's value ([`Reply::Param`]).
    Get(ParamId),
    /// Sets one parameter (idle only, [`Error::Busy`] during a grasp; the telemetry rate any
    /// time).
    Set(Param),
    /// Run the calibration sweep with no object: current offset with the bridge off, then a
    /// slow close and open of the free finger within the safe torque, bounded in time. Its
    /// rows come as [`Sample`]s in [`DeviceState::Sweeping`] (one per millisecond, whatever
    /// the telemetry rate), then [`EventKind::SweepEnded`]. Idle only.
    Calibrate,
    /// Close on the object: approach, contact, ΔT_a step, estimate, hold.
    Grasp,
    /// Let go: ramp the torque down, open back to rest, idle.
    Release,
    /// Torque off now, from any state; always honoured.
    Stop,
    /// Keep the current settings across power cycles.
    Store,
    /// Load the stored settings.
    Load,
    /// Reset the controller.
    Reboot,
    /// The drive constants and control period the controller converts its readings with
    /// ([`Reply::Drive`]): what a host needs to turn recorded raw samples back into θa and
    /// T_a, or to replay them through the same controller.
    Drive,
}

impl Command {
    /// Number of command variants (the wire tags are `0..COUNT`).
    pub const COUNT: u32 = 12;
}

/// A settable parameter's name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamId {
    /// Torque step ΔT_a after contact (N·m).
    DeltaTa,
    /// How the step is applied.
    StepShape,
    /// Which estimator the firmware runs.
    Estimator,
    /// Largest actuator speed during the approach (rad/s).
    ApproachSpeed,
    /// Torque at which the approach gives up without a contact (N·m).
    ApproachTorqueMax,
    /// Telemetry samples per second (Hz; 0 = off).
    TelemetryRate,
    /// The simulated scene (QEMU build only).
    Scene,
    /// Whether the contact is seated in static stages before the step (more accurate on a
    /// drive with friction) or the step starts at the contact (the estimate known sooner).
    Seating,
}

impl ParamId {
    /// Every parameter.
    pub const ALL: [ParamId; 8] = [
        ParamId::DeltaTa,
        ParamId::StepShape,
        ParamId::Estimator,
        ParamId::ApproachSpeed,
        ParamId::ApproachTorqueMax,
        ParamId::TelemetryRate,
        ParamId::Scene,
        ParamId::Seating,
    ];

    /// The name used on the command line and in messages.
    pub const fn name(self) -> &'static str {
        match self {
            ParamId::DeltaTa => "delta_ta_nm",
            ParamId::StepShape => "step_ramp_nm_per_s",
            ParamId::Estimator => "estimator",
            ParamId::ApproachSpeed => "approach_speed_rad_s",
            ParamId::ApproachTorqueMax => "approach_max_nm",
            ParamId::TelemetryRate => "telemetry_hz",
            ParamId::Scene => "scene",
            ParamId::Seating => "seating",
        }
    }

    /// The parameter with this [`ParamId::name`].
    pub fn from_name(name: &str) -> Option<ParamId> {
        ParamId::ALL.into_iter().find(|p| p.name() == name)
    }

    /// The accepted numeric range (inclusive), for numeric parameters; what the firmware
    /// checks and what [`Error::BadValue`] reports.
    pub const fn range(self) -> Option<Range> {
        match self {
            ParamId::DeltaTa => Some(Range {
                min: 0.05,
                max: 1.5,
            }),
            // 0 = a step; otherwise the ramp rate (N·m/s).
            ParamId::StepShape => Some(Range {
                min: 0.0,
                max: 100.0,
            }),
            ParamId::ApproachSpeed => Some(Range {
                min: 0.05,
                max: 5.0,
            }),
            ParamId::ApproachTorqueMax => Some(Range { min: 0.1, max: 2.0 }),
            ParamId::TelemetryRate => Some(Range {
                min: 0.0,
                max: 10_000.0,
            }),
            ParamId::Estimator | ParamId::Scene | ParamId::Seating => None,
        }
    }
}

/// An inclusive range of accepted values, in the parameter's unit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Range {
    /// Smallest accepted value.
    pub min: f64,
    /// Largest accepted value.
    pub max: f64,
}

impl Range {
    /// True when `v` is a number inside the range.
    pub fn contains(&self, v: f64) -> bool {
        v >= self.min && v <= self.max
    }
}

/// How the torque is raised by ΔT_a after contact.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum StepShape {
    /// The reference jumps by ΔT_a in one tick.
    Step,
    /// The reference rises at this rate (N·m/s).
    RampNmPerS(f64),
}

/// The estimator the firmware runs on a settled step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Estimator {
    /// The two-point method K̂c = ΔT_a/Δθa.
    TwoPoint,
    /// The path fit of the whole contact-to-settle path.
    PathFit,
}

/// A parameter with its value.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Param {
    /// ΔT_a (N·m).
    DeltaTaNm(f64),
    /// The step's shape.
    StepShape(StepShape),
    /// The estimator.
    Estimator(Estimator),
    /// Largest approach speed (rad/s).
    ApproachSpeedRadS(f64),
    /// Approach torque ceiling (N·m).
    ApproachMaxNm(f64),
    /// Telemetry samples per second (Hz; 0 = off).
    TelemetryHz(u16),
    /// The simulated scene (QEMU build).
    Scene(SceneName),
    /// Seat the contact before the step (`true`) or step at the contact (`false`).
    Seating(bool),
}

impl Param {
    /// Which parameter this is.
    pub fn id(&self) -> ParamId {
        match self {
            Param::DeltaTaNm(_) => ParamId::DeltaTa,
            Param::StepShape(_) => ParamId::StepShape,
            Param::Estimator(_) => ParamId::Estimator,
            Param::ApproachSpeedRadS(_) => ParamId::ApproachSpeed,
            Param::ApproachMaxNm(_) => ParamId::ApproachTorqueMax,
            Param::TelemetryHz(_) => ParamId::TelemetryRate,
            Param::Scene(_) => ParamId::Scene,
            Param::Seating(_) => ParamId::Seating,
        }
    }

    /// The numeric value checked against [`ParamId::range`] (a step counts as rate 0).
    pub fn number(&self) -> Option<f64> {
        match self {
            Param::DeltaTaNm(v) | Param::ApproachSpeedRadS(v) | Param::ApproachMaxNm(v) => Some(*v),
            Param::StepShape(StepShape::Step) => Some(0.0),
            Param::StepShape(StepShape::RampNmPerS(r)) => Some(*r),
            Param::TelemetryHz(h) => Some(f64::from(*h)),
            Param::Estimator(_) | Param::Scene(_) | Param::Seating(_) => None,
        }
    }

    /// Checks a numeric value against its range: `Err(Error::BadValue)` names the parameter,
    /// the value and the range (NaN is out of every range).
    pub fn check(&self) -> Result<(), Error> {
        let id = self.id();
        match (self.number(), id.range()) {
            (Some(v), Some(r)) if !r.contains(v) => Err(Error::BadValue {
                param: id,
                value: v,
                range: r,
            }),
            _ => Ok(()),
        }
    }
}

/// The device's state as the host sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum DeviceState {
    /// Bridge off, waiting for a command.
    Idle,
    /// Measuring the current offset (bridge off).
    Calibrating,
    /// The calibration sweep: closing and opening the free finger.
    Sweeping,
    /// Closing, watching for contact.
    Approach,
    /// Contact found, the impact dying out and the loading points taken.
    Seating,
    /// Torque rising by ΔT_a.
    Step,
    /// Waiting for θa to settle.
    Settling,
    /// Estimate running.
    Estimating,
    /// Estimate delivered, holding the object.
    Holding,
    /// Torque ramping down.
    Releasing,
    /// Opening back to the rest pose.
    Opening,
    /// Torque off on a stop command.
    Stopped,
    /// Safe state after a fault.
    Fault(Fault),
}

impl DeviceState {
    /// A stable snake_case name.
    pub const fn name(&self) -> &'static str {
        match self {
            DeviceState::Idle => "idle",
            DeviceState::Calibrating => "calibrating",
            DeviceState::Sweeping => "sweeping",
            DeviceState::Approach => "approach",
            DeviceState::Seating => "seating",
            DeviceState::Step => "step",
            DeviceState::Settling => "settling",
            DeviceState::Estimating => "estimating",
            DeviceState::Holding => "holding",
            DeviceState::Releasing => "releasing",
            DeviceState::Opening => "opening",
            DeviceState::Stopped => "stopped",
            DeviceState::Fault(_) => "fault",
        }
    }
}

/// A controller fault: its kind and one number that qualifies it (the kind's unit).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Fault {
    /// What went wrong.
    pub kind: FaultKind,
    /// The value that tripped it (e.g. µA for over-current, counts for an encoder jump).
    pub value: i32,
}

/// The controller's fault kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[allow(missing_docs)] // the names are the controller's fault reasons
pub enum FaultKind {
    EncoderJump,
    EncoderMismatch,
    AdcCode,
    AdcOffset,
    AdcRail,
    OverCurrent,
    Stall,
    NoContact,
    SettleTimeout,
    EstimateTimeout,
    SecondContact,
    NoMotion,
    LossOfContact,
    EstimateOutOfRange,
    SupervisorStalled,
    /// The host connection was lost during a grasp: torque off.
    HostLost,
    /// The rest check found no open stop (the encoder cannot be zeroed): torque off.
    RestNotFound,
}

/// What the device sends.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum DeviceMsg {
    /// The answer to the request with this id.
    Reply {
        /// The request's id (0 when the request could not be read).
        id: u16,
        /// Done, or why not.
        result: Result<Reply, Error>,
    },
    /// A state transition, as it happens.
    Event(Event),
    /// A contact and its estimate.
    Contact(Contact),
    /// A telemetry sample.
    Sample(Sample),
}

/// A successful answer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Reply {
    /// Done.
    Ack,
    /// The device's side of the version exchange.
    Hello {
        /// The device's [`VERSION`].
        version: u8,
        /// Firmware name and version.
        firmware: Name,
        /// Board name.
        board: Name,
    },
    /// State and settings.
    Status(Status),
    /// A parameter's value.
    Param(Param),
    /// The drive constants of the next (or current) grasp.
    Drive(Drive),
}

/// The controller's drive constants and control period, as the firmware uses them (the
/// values of the build's finger file, or of the selected scene on the simulated board).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Drive {
    /// Control period (s).
    pub dt_s: f64,
    /// Motor turns per turn of the input crank.
    pub gear_ratio: f64,
    /// Transmission efficiency, (0, 1].
    pub efficiency: f64,
    /// Motor torque constant (N·m/A).
    pub kt_nm_per_a: f64,
    /// Motor terminal resistance (Ω).
    pub resistance_ohm: f64,
    /// Bridge supply at full duty (V).
    pub bus_v: f64,
    /// Encoder counts per motor turn, quadrature ×4.
    pub counts_per_rev: f64,
    /// Motor current per ADC code (A/code).
    pub amps_per_code: f64,
    /// ADC code at zero current.
    pub zero_code: f64,
    /// Absolute model angle θa at the rest pose, where the encoder reads zero (rad).
    pub theta_a_rest_rad: f64,
}

/// The device's status.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// Current state.
    pub state: DeviceState,
    /// Control ticks since power-up.
    pub tick: u32,
    /// Grasps started since power-up.
    pub grasps: u16,
    /// The settings the next grasp uses.
    pub settings: Settings,
    /// The simulated scene (QEMU build), `None` on a real finger.
    pub scene: Option<SceneName>,
    /// True while the H-bridge drives the motor.
    pub bridge_on: bool,
    /// Where the settings came from (the store, or the build's defaults and why).
    pub settings_source: SettingsSource,
    /// A `set` changed them since they were loaded or stored.
    pub settings_changed: bool,
}

/// Where the settings in use came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SettingsSource {
    /// The build's defaults: the store held nothing usable.
    Defaults {
        /// Why the store was not used.
        why: StoreFailure,
    },
    /// The settings store (at boot, or by `load` or `store`).
    Store,
}

/// Why a request was refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Error {
    /// The command tag is not one this version knows.
    UnknownCommand {
        /// The tag received.
        tag: u32,
    },
    /// A value outside its range.
    BadValue {
        /// The parameter.
        param: ParamId,
        /// The value received (its unit is the parameter's).
        value: f64,
        /// The accepted range.
        range: Range,
    },
    /// A name or choice this build does not know (e.g. a scene name).
    UnknownChoice {
        /// The parameter.
        param: ParamId,
    },
    /// The command needs the idle state; the device is in this one.
    Busy {
        /// The current state.
        state: DeviceState,
    },
    /// A fault is latched: only stop, status, hello and reboot are accepted.
    FaultLatched {
        /// The latched fault.
        fault: Fault,
    },
    /// The request's frame could not be read.
    BadFrame(FrameError),
    /// The host speaks another protocol version.
    VersionMismatch {
        /// The host's.
        host: u8,
        /// The device's.
        device: u8,
    },
    /// The controller refused the configuration these settings give (the grasp did not start).
    ConfigRejected,
    /// This build does not do that (yet).
    NotSupported {
        /// What.
        what: Unsupported,
    },
    /// The settings store could not do a `store` or `load` (the settings in use are unchanged).
    Store {
        /// Why.
        why: StoreFailure,
    },
}

/// Why a `store` or `load` of the settings in flash failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum StoreFailure {
    /// `load`: the store holds no settings yet.
    Empty,
    /// `load`: no slot holds a valid record (bad magic, length or CRC).
    Corrupt,
    /// `load`: the newest record is of another settings layout.
    Foreign,
    /// `load`: the record is intact but its settings do not decode or are out of range.
    Invalid,
    /// The flash refused an erase, program or read, or the store does not fit it.
    Flash,
}

/// Features a build may lack.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Unsupported {
    /// The calibration sequence.
    Calibrate,
    /// Settings in flash (store/load).
    SettingsStore,
    /// The named estimator is not linked into this build.
    Estimator(Estimator),
    /// Scene selection (a real finger).
    Scene,
    /// Reboot on command.
    Reboot,
}

/// A state transition, with the control tick it happened at.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Event {
    /// Control ticks since power-up.
    pub tick: u32,
    /// What happened.
    pub kind: EventKind,
}

/// The kinds of [`Event`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum EventKind {
    /// A grasp started (its number since power-up).
    GraspStarted {
        /// Grasp number, from 1.
        grasp: u16,
    },
    /// Current offset calibrated; approach starts.
    Calibrated,
    /// Contact detected.
    ContactDetected {
        /// θa at the back-dated contact (µrad).
        theta_a_urad: i32,
        /// T_a at the contact (µN·m).
        torque_unm: i32,
    },
    /// The reference reached T_a,c + ΔT_a.
    StepDone,
    /// θa settled; the estimate runs.
    Settled,
    /// The estimate was delivered (the [`Contact`] follows).
    Estimated,
    /// Holding the object.
    Holding,
    /// Releasing.
    Releasing,
    /// Back at rest, bridge off, idle.
    Idle,
    /// Torque off on a stop command (the event's tick is when the bridge went off).
    Stopped {
        /// Tick at which the stop command was decoded.
        requested_tick: u32,
    },
    /// Safe state after a fault.
    Fault(Fault),
    /// The calibration sweep started (current offset first, then the sweep).
    SweepStarted,
    /// The calibration sweep ended, bridge off, idle (or in the fault it reported).
    SweepEnded {
        /// How it ended.
        end: SweepEnd,
        /// Rows it recorded.
        rows: u32,
    },
}

/// How a calibration sweep ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SweepEnd {
    /// Closed and opened through its range: the record is complete.
    Done,
    /// A fault tripped it (reported in its own event).
    Fault,
    /// The finger ran past the angle limit.
    AngleLimit,
    /// The time limit passed before the finger was back.
    Timeout,
    /// Stopped by the host (a stop command, or the link lost).
    Stopped,
}

impl SweepEnd {
    /// A stable snake_case name.
    pub const fn name(&self) -> &'static str {
        match self {
            SweepEnd::Done => "done",
            SweepEnd::Fault => "fault",
            SweepEnd::AngleLimit => "angle_limit",
            SweepEnd::Timeout => "timeout",
            SweepEnd::Stopped => "stopped",
        }
    }
}

/// Where the contact is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Phalanx {
    /// On the proximal phalanx.
    Proximal,
    /// On the distal phalanx.
    Distal,
    /// Proximal, or distal near the middle joint.
    ProximalOrNearO2,
}

/// One contact and its estimate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Contact {
    /// Grasp number since power-up.
    pub grasp: u16,
    /// The estimator that produced it.
    pub estimator: Estimator,
    /// The phalanx.
    pub phalanx: Phalanx,
    /// Distal contact location from the middle joint (µm), when distal or ambiguous.
    pub k2_um: Option<i32>,
    /// One standard deviation of k2 (µm), when the estimator gives one.
    pub sigma_um: Option<i32>,
    /// Object radius at the contact (µm), when observed.
    pub r_um: Option<i32>,
    /// The two-point reference k2 (µm), when computed beside another estimator.
    pub two_point_k2_um: Option<i32>,
    /// K̂c = ΔT_a/Δθa (µN·m/rad); 0 where the estimator fits none (the path fit's proximal
    /// answer).
    pub kc_hat_unm_per_rad: i32,
    /// θa at contact (µrad).
    pub theta_a_c_urad: i32,
    /// T_a at contact (µN·m).
    pub ta_c_unm: i32,
    /// ΔT_a applied (µN·m).
    pub delta_ta_unm: i32,
    /// Δθa (µrad).
    pub delta_theta_a_urad: i32,
    /// True when the estimator trusts the result.
    pub good: bool,
}

/// One telemetry sample.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// Control tick.
    pub tick: u32,
    /// θa (µrad).
    pub theta_a_urad: i32,
    /// Measured T_a (µN·m).
    pub torque_unm: i32,
    /// Torque reference (µN·m).
    pub torque_ref_unm: i32,
    /// Duty (±the controller's full scale).
    pub duty: i16,
    /// The state.
    pub state: DeviceState,
    /// Raw encoder count the tick read (×4 quadrature, wrapping): with `current_code`, what
    /// an exact replay of the controller needs.
    pub encoder_count: u16,
    /// Raw current-sense ADC code the tick read.
    pub current_code: u16,
}

impl Message for DeviceMsg {}

impl Message for Request {
    // The firmware's one request decoder, compiled here (see `Message::decode_frame`).
    #[inline(never)]
    fn decode_frame(frame: &mut [u8]) -> Result<Self, FrameError> {
        frame::decode(frame)
    }

    fn classify(body: &[u8]) -> FrameError {
        // A request whose id reads but whose command tag is beyond this version's: an
        // unknown command (answerable with the id), not a broken frame.
        let Ok((id, rest)) = postcard::take_from_bytes::<u16>(body) else {
            return FrameError::Malformed;
        };
        match postcard::take_from_bytes::<u32>(rest) {
            Ok((tag, _)) if tag >= Command::COUNT => FrameError::UnknownCommand { id, tag },
            _ => FrameError::Malformed,
        }
    }
}

impl DeviceMsg {
    /// Encodes this message as one frame into `out` ([`encode`]); returns the frame's length.
    /// Not generic: the encoder is compiled once, here, with this crate's optimisation level
    /// (size, in the firmware's release profile) instead of in each caller.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        encode(self, out)
    }
}
