//! Device mode (feature `device`): the host drives the finger in the crates/proto protocol over
//! a byte [`Transport`]: USB CDC-ACM on the board (`board::usb`), the mps2-an386 CMSDK UART0 on
//! QEMU ([`uart`]). Many grasps per power-up, settings (and on QEMU the simulated scene)
//! changed between grasps, stop honoured from any state.
//!
//! The sampling task and this module meet in a few atomics: [`HALT`] (bridge off on the next
//! tick, whatever the controller asks), [`ACTIVE`] (the controller is ticked) and the host's
//! last-heard tick, from which the sampling task switches the bridge off when the host goes
//! silent in the middle of a grasp.

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use grasp::{Event as GEvent, FaultReason, Located, Quality, State};
use proto::{
    Contact, DeviceMsg, DeviceState, Error, Event, EventKind, Fault, FaultKind, Phalanx, Reply,
    Request, Sample, SceneName, Settings,
};

/// Set by `stop` (and on a lost host): the sampling task switches the bridge off at its next
/// tick and does not tick the controller.
pub static HALT: AtomicBool = AtomicBool::new(true);
/// The controller is ticked (a grasp is under way or holding).
pub static ACTIVE: AtomicBool = AtomicBool::new(false);
/// Tick at which the host's last frame arrived.
pub static LAST_RX_TICK: AtomicU32 = AtomicU32::new(0);
/// Set by the sampling task when it halted for a silent host.
pub static HOST_LOST: AtomicBool = AtomicBool::new(false);
/// A calibration sweep runs (the loop is a [`grasp::ControlLoop::for_sweep`]); cleared by
/// whoever ends it first: the sampling task when the sweep finishes, or a stop, a release
/// or a lost host.
pub static SWEEPING: AtomicBool = AtomicBool::new(false);
/// Rows the current (or last) calibration sweep recorded.
pub static SWEEP_ROWS: AtomicU32 = AtomicU32::new(0);
/// Telemetry decimation (ticks per sample; 0 = no samples).
pub static DECIMATION: AtomicU32 = AtomicU32::new(200);

/// During the motion of a grasp (calibration to estimate) the host must be heard at least
/// this often (ticks: 2 s at 10 kHz); `pts board` polls the status meanwhile.
pub const HOST_TIMEOUT_TICKS: u32 = 20_000;

/// Bytes of encoded frames waiting for the link.
pub const TX_QUEUE: usize = 1024;
/// Messages waiting to be encoded: a whole telemetry queue's burst
/// ([`crate::telemetry::QUEUE`]) and the replies and events around it.
pub const OUT_QUEUE: usize = 48;
const _: () = assert!(TX_QUEUE >= 2 * proto::MAX_FRAME);

/// True in the states where the finger moves under the controller's command and a silent
/// host stops the grasp (or the release).
pub fn in_motion(state: State) -> bool {
    matches!(
        state,
        State::Calibrating
            | State::Approach
            | State::Seating
            | State::Step
            | State::Settling
            | State::Estimating
            | State::Releasing
            | State::Opening
    )
}

/// The byte link to the host, as device mode uses it: non-blocking reads and writes.
pub trait Transport {
    /// Reads what has arrived into `buf`; returns the count (0: nothing now).
    fn read(&mut self, buf: &mut [u8]) -> usize;
    /// Hands as many of `bytes` to the link as it takes now; returns the count.
    fn write(&mut self, bytes: &[u8]) -> usize;
    /// Whether a host is attached: false once it let go of the link (USB: port closed or
    /// bus suspended), which stops a grasp in motion at once.
    fn open(&self) -> bool;
}

/// This build's transport.
#[cfg(not(feature = "qemu"))]
pub use crate::board::usb::Usb as Link;
/// This build's transport.
#[cfg(feature = "qemu")]
pub use uart::Uart as Link;

/// The CMSDK APB UART0 of mps2-an386 (QEMU connects it to its first `-serial`).
#[cfg(feature = "qemu")]
pub mod uart {
    const BASE: usize = 0x4000_4000;
    const DATA: *mut u32 = BASE as *mut u32;
    const STATE: *mut u32 = (BASE + 0x04) as *mut u32;
    const CTRL: *mut u32 = (BASE + 0x08) as *mut u32;
    const INTSTATUS: *mut u32 = (BASE + 0x0C) as *mut u32;
    const BAUDDIV: *mut u32 = (BASE + 0x10) as *mut u32;

    /// UART0 as device mode's [`super::Transport`].
    pub struct Uart(());

    /// Transmitter and receiver on, the receive interrupt on (IRQ 0, `OTG_FS` in src/sim/pac.rs).
    pub fn init() -> Uart {
        // SAFETY: UART0's registers, used by nobody else.
        unsafe {
            BAUDDIV.write_volatile(16);
            CTRL.write_volatile(0b1011);
        }
        Uart(())
    }

    impl super::Transport for Uart {
        fn read(&mut self, buf: &mut [u8]) -> usize {
            let mut n = 0;
            for slot in buf.iter_mut() {
                match read() {
                    Some(b) => *slot = b,
                    None => break,
                }
                n += 1;
            }
            n
        }

        fn write(&mut self, bytes: &[u8]) -> usize {
            bytes.iter().take_while(|&&b| try_write(b)).count()
        }

        /// A UART cannot tell; the host's silence is what counts.
        fn open(&self) -> bool {
            true
        }
    }

    /// The received byte, if any; acknowledges the receive interrupt.
    pub fn read() -> Option<u8> {
        // SAFETY: UART0 register reads and the write-one-to-clear of its RX interrupt.
        unsafe {
            INTSTATUS.write_volatile(0b10);
            if STATE.read_volatile() & 0b10 != 0 {
                Some(DATA.read_volatile() as u8)
            } else {
                None
            }
        }
    }

    /// Sends a byte if the transmitter has room.
    pub fn try_write(b: u8) -> bool {
        // SAFETY: UART0 register read and data write.
        unsafe {
            if STATE.read_volatile() & 0b1 == 0 {
                DATA.write_volatile(u32::from(b));
                true
            } else {
                false
            }
        }
    }
}

/// What the host side of the device keeps between commands. `repr(C)` with the queues last:
/// the small fields stay within the reach of Thumb-2's 12-bit load and store offsets.
#[repr(C)]
pub struct Device {
    /// The next grasp's settings.
    pub settings: Settings,
    /// The simulated scene the next grasp uses.
    pub scene: SceneName,
    /// Grasps started since power-up.
    pub grasps: u16,
    /// Estimator of the grasp under way.
    pub estimator: proto::Estimator,
    /// The state outside a grasp (idle, stopped, a fault) or `None` during one.
    pub rest: Option<DeviceState>,
    /// Messages dropped for a full message queue.
    pub tx_dropped: u32,
    /// The link to the host.
    pub io: Link,
    /// Where `settings` came from.
    pub source: proto::SettingsSource,
    /// A `set` changed `settings` since they were loaded or stored.
    pub changed: bool,
    /// The request decoder.
    pub rx: proto::Decoder<Request, { proto::MAX_FRAME }>,
    /// Encoded frames waiting for the link.
    pub tx: heapless::Deque<u8, TX_QUEUE>,
    /// Messages waiting to be encoded. Only the link's task ([`Device::flush`]) encodes and
    /// touches the link: the serialiser and the USB stack stay out of the other tasks.
    pub out: heapless::Deque<DeviceMsg, OUT_QUEUE>,
}

impl Device {
    /// Idle with the build's settings and scene, talking over `io`.
    pub fn new(scene: &str, io: Link) -> Self {
        let settings = crate::ctl::default_settings();
        set_decimation(settings.telemetry_hz);
        Self {
            settings,
            scene: SceneName::try_from(scene).unwrap_or_default(),
            grasps: 0,
            estimator: settings.estimator,
            rest: Some(DeviceState::Idle),
            rx: proto::Decoder::new(),
            out: heapless::Deque::new(),
            tx: heapless::Deque::new(),
            tx_dropped: 0,
            io,
            source: proto::SettingsSource::Defaults {
                why: proto::StoreFailure::Empty,
            },
            changed: false,
        }
    }

    /// Queues a message for the link's task, which encodes and sends it ([`Device::flush`]).
    pub fn send(&mut self, msg: DeviceMsg) {
        if self.out.push_back(msg).is_err() {
            self.tx_dropped = self.tx_dropped.wrapping_add(1);
        }
    }

    /// Nothing waits to be encoded or sent.
    pub fn drained(&self) -> bool {
        self.out.is_empty() && self.tx.is_empty()
    }

    /// Encodes queued messages into the TX queue (whole frames only, while it has room for one)
    /// and hands queued bytes to the link while it takes them. The link's task only.
    pub fn flush(&mut self) {
        loop {
            while self.tx.capacity() - self.tx.len() >= proto::MAX_FRAME {
                let Some(msg) = self.out.front() else {
                    break;
                };
                encode_into(&mut self.tx, msg);
                self.out.pop_front();
            }
            let (front, _) = self.tx.as_slices();
            let n = match front.len() {
                0 => break,
                _ => self.io.write(front),
            };
            if n == 0 {
                break;
            }
            for _ in 0..n {
                self.tx.pop_front();
            }
        }
    }

    /// Replies to request `id`.
    pub fn reply(&mut self, id: u16, result: Result<Reply, Error>) {
        if let Err(e) = &result {
            log_error(e);
        }
        self.send(DeviceMsg::Reply { id, result });
    }

    /// The state the host sees outside a grasp (`controller`: the controller's state, for
    /// a grasp under way).
    pub fn device_state(&self, controller: State) -> DeviceState {
        if HOST_LOST.load(Ordering::Relaxed) {
            return DeviceState::Fault(host_lost(HOST_TIMEOUT_TICKS));
        }
        match self.rest {
            Some(s) => s,
            None => state(controller),
        }
    }

    /// A controller event: forwarded, with the contact after an estimate.
    pub fn event(&mut self, ev: &GEvent) {
        let (tick, kind) = match *ev {
            GEvent::Calibrated { tick, .. } => (tick, EventKind::Calibrated),
            GEvent::ContactDetected {
                tick,
                theta_a_urad,
                torque_unm,
                ..
            } => (
                tick,
                EventKind::ContactDetected {
                    theta_a_urad,
                    torque_unm,
                },
            ),
            GEvent::Seated { .. } => return,
            GEvent::StepDone { tick } => (tick, EventKind::StepDone),
            GEvent::Settled { tick, .. } => (tick, EventKind::Settled),
            GEvent::Estimated { tick, result } => {
                self.send(DeviceMsg::Event(Event {
                    tick,
                    kind: EventKind::Estimated,
                }));
                let c = Contact {
                    grasp: self.grasps,
                    estimator: self.estimator,
                    phalanx: match result.located {
                        Located::Proximal => Phalanx::Proximal,
                        Located::Distal => Phalanx::Distal,
                        Located::ProximalOrNearO2 => Phalanx::ProximalOrNearO2,
                    },
                    k2_um: result.k2_um,
                    sigma_um: result.k2_sigma_um,
                    r_um: result.radius_um,
                    two_point_k2_um: result.two_point_k2_um,
                    kc_hat_unm_per_rad: result.kc_hat_unm_per_rad,
                    theta_a_c_urad: result.theta_a_c_urad,
                    ta_c_unm: result.ta_c_unm,
                    delta_ta_unm: result.delta_ta_unm,
                    delta_theta_a_urad: result.delta_theta_a_urad,
                    good: result.quality == Quality::Good,
                };
                self.send(DeviceMsg::Contact(c));
                return;
            }
            GEvent::Holding { tick } => (tick, EventKind::Holding),
            GEvent::Releasing { tick } => (tick, EventKind::Releasing),
            GEvent::Released { tick } => {
                // Open and the bridge off: the device is idle until the next command.
                HALT.store(true, Ordering::SeqCst);
                ACTIVE.store(false, Ordering::SeqCst);
                self.rest = Some(DeviceState::Idle);
                (tick, EventKind::Idle)
            }
            GEvent::Fault { tick, reason } => (tick, EventKind::Fault(fault(reason))),
        };
        if let EventKind::Fault(f) = kind {
            self.rest = Some(DeviceState::Fault(f));
        }
        self.send(DeviceMsg::Event(Event { tick, kind }));
    }

    /// A telemetry sample.
    pub fn sample(&mut self, out: Sample) {
        self.send(DeviceMsg::Sample(out));
    }

    /// The calibration sweep is over (`end`): reported, and the device idle when it ended on
    /// its own (a fault's own event sets the fault; a stop or release sets its state).
    pub fn sweep_ended(&mut self, tick: u32, end: proto::SweepEnd, rows: u32) {
        use proto::SweepEnd as E;
        if matches!(end, E::Done | E::AngleLimit | E::Timeout)
            && self.rest == Some(DeviceState::Sweeping)
        {
            self.rest = Some(DeviceState::Idle);
        }
        self.send(DeviceMsg::Event(Event {
            tick,
            kind: EventKind::SweepEnded { end, rows },
        }));
    }

    /// Ends a sweep the host stopped (stop, release, link lost), if one runs.
    pub fn sweep_stopped(&mut self, tick: u32) {
        if SWEEPING.swap(false, Ordering::SeqCst) {
            self.sweep_ended(
                tick,
                proto::SweepEnd::Stopped,
                SWEEP_ROWS.load(Ordering::Relaxed),
            );
        }
    }
}

/// Appends `msg`'s frame to `tx` (which has room for a whole frame); one copy of the encoder.
#[inline(never)]
fn encode_into(tx: &mut heapless::Deque<u8, TX_QUEUE>, msg: &DeviceMsg) {
    let mut buf = [0u8; proto::MAX_FRAME];
    match msg.encode(&mut buf) {
        Ok(n) => {
            for &b in buf.get(..n).unwrap_or(&[]) {
                let _ = tx.push_back(b);
            }
        }
        Err(e) => defmt::error!("proto: message not encodable: {}", e),
    }
}

/// The protocol's view of the controller's drive constants.
pub fn drive(d: &grasp::DriveConfig) -> proto::Drive {
    proto::Drive {
        dt_s: d.dt_s,
        gear_ratio: d.gear_ratio,
        efficiency: d.efficiency,
        kt_nm_per_a: d.kt_nm_per_a,
        resistance_ohm: d.resistance_ohm,
        bus_v: d.bus_v,
        counts_per_rev: d.encoder_counts_per_rev,
        amps_per_code: d.amps_per_code,
        zero_code: d.adc_zero_code,
        theta_a_rest_rad: d.theta_a_rest_rad,
    }
}

/// Sets the telemetry decimation for a rate (Hz) at the 10 kHz loop.
pub fn set_decimation(hz: u16) {
    let n = if hz == 0 {
        0
    } else {
        (10_000 / u32::from(hz)).max(1)
    };
    DECIMATION.store(n, Ordering::Relaxed);
}

/// The protocol's view of how a sweep ended.
pub fn sweep_end(p: grasp::calibrate::Phase) -> Option<proto::SweepEnd> {
    use grasp::calibrate::{AbortReason, Phase};
    match p {
        Phase::Done => Some(proto::SweepEnd::Done),
        Phase::Aborted(AbortReason::Fault) => Some(proto::SweepEnd::Fault),
        Phase::Aborted(AbortReason::AngleLimit) => Some(proto::SweepEnd::AngleLimit),
        Phase::Aborted(AbortReason::Timeout) => Some(proto::SweepEnd::Timeout),
        _ => None,
    }
}

/// The protocol's view of the controller's state.
pub fn state(s: State) -> DeviceState {
    match s {
        State::Init | State::Calibrating => DeviceState::Calibrating,
        State::Approach => DeviceState::Approach,
        State::Seating => DeviceState::Seating,
        State::Step => DeviceState::Step,
        State::Settling => DeviceState::Settling,
        State::Estimating => DeviceState::Estimating,
        State::Holding => DeviceState::Holding,
        State::Releasing => DeviceState::Releasing,
        State::Opening => DeviceState::Opening,
        State::Done => DeviceState::Idle,
        State::Fault(r) => DeviceState::Fault(fault(r)),
    }
}

/// The protocol's view of a controller fault.
pub fn fault(r: FaultReason) -> Fault {
    let (kind, value) = match r {
        FaultReason::EncoderJump { step_counts } => (FaultKind::EncoderJump, step_counts),
        FaultReason::EncoderMismatch { emf_mv, .. } => (FaultKind::EncoderMismatch, emf_mv),
        FaultReason::AdcCode { code } => (FaultKind::AdcCode, i32::from(code)),
        FaultReason::AdcOffset { offset_q8 } => (FaultKind::AdcOffset, offset_q8),
        FaultReason::AdcRail { code } => (FaultKind::AdcRail, i32::from(code)),
        FaultReason::OverCurrent { current_ua } => (FaultKind::OverCurrent, current_ua),
        FaultReason::Stall => (FaultKind::Stall, 0),
        FaultReason::NoContact => (FaultKind::NoContact, 0),
        FaultReason::SettleTimeout => (FaultKind::SettleTimeout, 0),
        FaultReason::EstimateTimeout => (FaultKind::EstimateTimeout, 0),
        FaultReason::SecondContact { kc_unm_per_rad } => (FaultKind::SecondContact, kc_unm_per_rad),
        FaultReason::NoMotion { dtheta_a_urad } => (FaultKind::NoMotion, dtheta_a_urad),
        FaultReason::LossOfContact { dtheta_a_urad } => (FaultKind::LossOfContact, dtheta_a_urad),
        FaultReason::EstimateOutOfRange { .. } => (FaultKind::EstimateOutOfRange, 0),
        FaultReason::SupervisorStalled { age_ticks } => (
            FaultKind::SupervisorStalled,
            age_ticks.min(i32::MAX as u32) as i32,
        ),
        FaultReason::RestNotFound { moved_counts, .. } => (FaultKind::RestNotFound, moved_counts),
    };
    Fault { kind, value }
}

/// The fault a silent host leaves (value: ticks the host had been silent, at least
/// [`HOST_TIMEOUT_TICKS`]).
pub fn host_lost(ticks: u32) -> Fault {
    Fault {
        kind: FaultKind::HostLost,
        value: ticks.min(i32::MAX as u32) as i32,
    }
}

fn log_error(e: &Error) {
    match e {
        Error::BadValue {
            param,
            value,
            range,
        } => defmt::warn!(
            "HOST bad value {=str}={=f64} (allowed {=f64}..={=f64})",
            param.name(),
            value,
            range.min,
            range.max
        ),
        Error::BadFrame(f) => defmt::warn!("HOST bad frame: {}", f),
        Error::UnknownCommand { tag } => defmt::warn!("HOST unknown command tag {=u32}", tag),
        Error::Busy { state } => defmt::warn!("HOST busy ({=str})", state.name()),
        _ => defmt::warn!("HOST request refused"),
    }
}
