//! Messages from the control and estimate tasks to the telemetry task (lowest priority).
//! Producers only ever `try_send`: a full queue drops the message and counts it, the control
//! loop never waits for the logger. The log lines are the interface of `cargo xtask demo/test`
//! and `pts trace`: the sample, event, plant and truth lines are defined in `proto::log`
//! (written here, by the host runner, and parsed there); keep the other prefixes and
//! `key=value` names stable.

use core::sync::atomic::{AtomicU32, Ordering};

use grasp::{Event, State};

/// Depth of the telemetry queue (messages).
pub const QUEUE: usize = 32;

/// Control ticks since reset: the defmt timestamp.
pub static TICKS: AtomicU32 = AtomicU32::new(0);
/// Messages dropped because the queue was full.
pub static DROPPED: AtomicU32 = AtomicU32::new(0);
/// Worst sampling-task work seen so far, in the board's cycle-counter units
/// (board: CPU cycles from DWT; QEMU with `-icount shift=0`: SysTick ticks of 40 instructions).
pub static WORK_MAX: AtomicU32 = AtomicU32::new(0);
/// Control tick of the worst sampling-task work.
pub static WORK_MAX_TICK: AtomicU32 = AtomicU32::new(0);
/// Sum of the sampling-task work (for the mean).
pub static WORK_SUM: AtomicU32 = AtomicU32::new(0);
/// Total time spent in the sampling task (stamp units), so a preempted task can subtract it.
pub static PREEMPT: AtomicU32 = AtomicU32::new(0);
/// Worst estimate-task work, same units.
pub static EST_WORK_MAX: AtomicU32 = AtomicU32::new(0);
/// Worst supervisor-task run (the state machine on one or more samples), same units,
/// sampling-task preemption subtracted.
pub static SUP_WORK_MAX: AtomicU32 = AtomicU32::new(0);
/// Ticks that found input waiting while the supervisor task was still pending or running
/// (it takes that input in the same run; nothing is lost unless the link overflows).
pub static SUP_BUSY: AtomicU32 = AtomicU32::new(0);

/// The sampling period, µs (the 10 kHz control loop counts [`TICKS`]).
pub const TICK_US: u64 = 100;

// `:us` lets probe-rs and the host decoder print seconds instead of bare tick counts.
defmt::timestamp!(
    "{=u64:us}",
    u64::from(TICKS.load(Ordering::Relaxed)) * TICK_US
);

/// A plant event and the plant's truth (simulated board only), in integers.
pub use sim_board::log::{PlantEventLine as PlantEvent, TruthLine as Truth};

/// One telemetry message.
#[derive(Clone, Copy, Debug)]
pub enum Msg {
    /// Decimated sample.
    Sample {
        /// Control tick.
        tick: u32,
        /// θa (µrad).
        theta_a_urad: i32,
        /// Measured T_a (µN·m).
        torque_unm: i32,
        /// Torque reference (µN·m).
        torque_ref_unm: i32,
        /// Duty (±10 000).
        duty: i16,
        /// State after the tick.
        state: State,
        /// Raw encoder count and ADC code the tick read (sent to the host in device mode;
        /// the defmt line leaves them out).
        #[cfg_attr(not(feature = "device"), allow(dead_code))]
        raw: (u16, u16),
    },
    /// A controller event, as it happened.
    Event(Event),
    /// A plant event (simulated board).
    Plant(PlantEvent),
    /// Plant truth (simulated board).
    Truth(Truth),
    /// The rest check is over: where the finger was at power-up.
    Rest(grasp::RestReport),
    /// The run is over.
    Done(Done),
    /// Device mode: one recorded tick of the calibration sweep (for the host only).
    #[cfg_attr(not(feature = "device"), allow(dead_code))]
    SweepRow(proto::Sample),
    /// Device mode: the calibration sweep is over (bridge off).
    #[cfg_attr(not(feature = "device"), allow(dead_code))]
    SweepEnd {
        /// Tick at which it ended.
        tick: u32,
        /// How.
        end: proto::SweepEnd,
        /// Rows recorded.
        rows: u32,
    },
    /// Device mode: the host went silent during a grasp; the bridge is off.
    #[cfg_attr(not(feature = "device"), allow(dead_code))]
    HostLost {
        /// Tick of the halt.
        tick: u32,
        /// Ticks since the host's last frame.
        silent_ticks: u32,
    },
}

/// End of a run.
#[derive(Clone, Copy, Debug)]
pub struct Done {
    /// Exit status: 0 estimate delivered, 2 controller fault (bridge off).
    pub status: i32,
    /// Final state.
    pub state: State,
    /// Bridge in the safe state.
    pub bridge_safe: bool,
    /// Control ticks run.
    pub ticks: u32,
}

/// Counts one dropped message.
pub fn dropped() {
    DROPPED.fetch_add(1, Ordering::Relaxed);
}

/// Keeps the maximum of a work counter; true when `v` is a new maximum.
pub fn record_max(slot: &AtomicU32, v: u32) -> bool {
    if v > slot.load(Ordering::Relaxed) {
        slot.store(v, Ordering::Relaxed);
        true
    } else {
        false
    }
}

/// Records the sampling task's work of one tick.
pub fn record_work(tick: u32, v: u32) {
    // Single writer (the sampling task): load + store is enough; saturate instead of wrapping.
    WORK_SUM.store(
        WORK_SUM.load(Ordering::Relaxed).saturating_add(v),
        Ordering::Relaxed,
    );
    if record_max(&WORK_MAX, v) {
        WORK_MAX_TICK.store(tick, Ordering::Relaxed);
    }
}

/// How long the `telstall` injection holds the telemetry task (control ticks): longer than
/// a Table 2 grasp, so the queue is full when the run ends.
pub const STALL_TICKS: u32 = 70_000;

/// Telemetry stall (test command only, `FINGER_FW_INJECT=telstall@TICK`): the first message
/// logged at or after TICK holds the telemetry task for [`STALL_TICKS`], so the queue fills
/// and every producer meets it full.
fn inject_stall() {
    static STALLED: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);
    if let Some(("telstall", at)) = crate::config::INJECT {
        let now = TICKS.load(Ordering::Relaxed);
        if now >= at && !STALLED.swap(true, Ordering::Relaxed) {
            defmt::info!("STALL telemetry held for {=u32} ticks", STALL_TICKS);
            while TICKS.load(Ordering::Relaxed).wrapping_sub(now) < STALL_TICKS {
                core::hint::spin_loop();
            }
        }
    }
}

/// Logs one message (runs in the telemetry task).
pub fn log(msg: &Msg) {
    inject_stall();
    match msg {
        Msg::Sample {
            tick,
            theta_a_urad,
            torque_unm,
            torque_ref_unm,
            duty,
            state,
            ..
        } => proto::log_line!(
            sample,
            defmt::info,
            tick,
            theta_a_urad,
            torque_unm,
            torque_ref_unm,
            duty,
            state
        ),
        Msg::Event(ev) => proto::log_line!(event, defmt::info, ev),
        Msg::Plant(p) => proto::log_line!(
            plant,
            defmt::info,
            p.kind,
            p.t_us,
            p.theta_a_urad,
            p.torque_unm,
            p.phalanx,
            p.k_um
        ),
        Msg::Truth(t) => proto::log_line!(
            truth,
            defmt::info,
            t.at,
            t.t_us,
            t.theta_a_urad,
            t.torque_unm,
            t.contact,
            t.k_um
        ),
        Msg::Rest(r) => defmt::info!(
            "REST power_up_urad={=i32} stop_ticks={=u32} done_ticks={=u32}",
            r.power_up_urad,
            r.stop_ticks,
            r.done_ticks
        ),
        Msg::SweepRow(_) => {}
        Msg::SweepEnd { tick, end, rows } => defmt::info!(
            "SWEEP ended at tick {=u32}: {=str} rows={=u32}",
            tick,
            end.name(),
            rows
        ),
        Msg::HostLost { tick, silent_ticks } => defmt::error!(
            "HOST lost at tick {=u32} (silent for {=u32} ticks): bridge off",
            tick,
            silent_ticks
        ),
        Msg::Done(d) => defmt::info!(
            "END status={=i32} state={} bridge_safe={=bool} ticks={=u32} dropped={=u32} work_max={=u32} work_max_tick={=u32} work_mean_x100={=u32} est_work_max={=u32} sup_work_max={=u32} sup_busy={=u32}",
            d.status,
            d.state,
            d.bridge_safe,
            d.ticks,
            DROPPED.load(Ordering::Relaxed),
            WORK_MAX.load(Ordering::Relaxed),
            WORK_MAX_TICK.load(Ordering::Relaxed),
            (u64::from(WORK_SUM.load(Ordering::Relaxed)) * 100 / u64::from(d.ticks.max(1))) as u32,
            EST_WORK_MAX.load(Ordering::Relaxed),
            SUP_WORK_MAX.load(Ordering::Relaxed),
            SUP_BUSY.load(Ordering::Relaxed)
        ),
    }
}
