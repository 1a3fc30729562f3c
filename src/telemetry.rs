//! Messages from the control and estimate tasks to the telemetry task (lowest priority).
//! The producers only ever `try_send`: a full queue drops the message and counts it, the
//! control loop never waits for the logger.

use core::sync::atomic::{AtomicU32, Ordering};

use crate::ctl::{Event, State};

/// Control ticks between two telemetry samples (1 kHz loop → 50 Hz θa/T_a/state stream).
pub const DECIMATION: u32 = 20;
/// Depth of the telemetry queue (messages).
pub const QUEUE: usize = 32;

/// Control ticks since reset: the defmt timestamp (ms of control time at 1 kHz).
pub static TICKS: AtomicU32 = AtomicU32::new(0);
/// Messages dropped because the queue was full.
pub static DROPPED: AtomicU32 = AtomicU32::new(0);

defmt::timestamp!("{=u32:010}", TICKS.load(Ordering::Relaxed));

/// One telemetry message.
#[derive(Clone, Copy, Debug)]
pub enum Msg {
    /// Decimated sample: tick, θa (µrad), T_a (µN·m), state.
    Sample {
        /// Control tick.
        tick: u32,
        /// θa (µrad).
        theta_a_urad: i32,
        /// T_a (µN·m).
        ta_unm: i32,
        /// State after the tick.
        state: State,
    },
    /// A controller event, as it happened.
    Event(Event),
    /// The run is over (QEMU: exit with this status after logging it).
    Done(Done),
}

/// End of a run: final state and, on the simulated board, the plant's truth.
#[derive(Clone, Copy, Debug)]
pub struct Done {
    /// Exit status: 0 estimate delivered, 2 controller fault (bridge off).
    pub status: i32,
    /// Final state.
    pub state: State,
    /// Bridge in the safe state.
    pub bridge_safe: bool,
    /// Plant truth: θa (µrad).
    pub truth_theta_a_urad: i32,
    /// Simulated time (µs).
    pub t_us: u32,
}

/// Counts one dropped message.
pub fn dropped() {
    DROPPED.fetch_add(1, Ordering::Relaxed);
}

/// Logs one message (runs in the telemetry task).
pub fn log(msg: &Msg) {
    match msg {
        Msg::Sample {
            tick,
            theta_a_urad,
            ta_unm,
            state,
        } => defmt::info!(
            "S tick={=u32} theta_a_urad={=i32} ta_unm={=i32} state={}",
            tick,
            theta_a_urad,
            ta_unm,
            state
        ),
        Msg::Event(ev) => defmt::info!("E {}", ev),
        Msg::Done(d) => defmt::info!(
            "END status={=i32} state={} bridge_safe={=bool} truth_theta_a_urad={=i32} t_us={=u32} dropped={=u32}",
            d.status,
            d.state,
            d.bridge_safe,
            d.truth_theta_a_urad,
            d.t_us,
            DROPPED.load(Ordering::Relaxed)
        ),
    }
}
