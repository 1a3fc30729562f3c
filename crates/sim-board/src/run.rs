//! The one run loop of the host runners (the tests, `pts sim`, `pts estimate`'s replay, the
//! firmware's host runner): a [`Controller`] and any [`Board`] driven tick by tick, the
//! estimate computed when the request is ready, every event handed to an [`Observer`].

use grasp::{
    Controller, EstimateError, EstimateRequest, EstimateResult, Event, Hardware, State, TickOutput,
};

use crate::PlantBoard;

/// A board the loop can drive: the hardware, and the passing of one control period.
pub trait Board: Hardware {
    /// One control period passes with what the controller commanded.
    fn advance(&mut self);
}

impl Board for PlantBoard {
    fn advance(&mut self) {
        PlantBoard::advance(self);
    }
}

/// When the estimate reaches the controller, and which state ends the run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Timing {
    /// In the tick that made the request ready, before the board advances; the run's end
    /// counts from the state after the delivery. The tools and the tests.
    Immediate,
    /// After the board advanced, as the firmware's estimate task runs after the sampling
    /// task; the run ends on the tick whose output reports a finished state. The firmware's
    /// host runner, whose log is compared with the QEMU firmware's.
    Firmware,
}

/// How long a run goes.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Ticks at most.
    pub max_ticks: u64,
    /// Ticks to go on after the controller holds, is done or faulted (`None`: to the end).
    pub extra_ticks: Option<u64>,
    /// When the estimate is delivered.
    pub timing: Timing,
}

/// What a runner does around the ticks. Only [`Observer::estimate`] is required.
pub trait Observer<B> {
    /// Before tick `n` (from 0): inject a fault, feed a recorded sample. `false` ends the run.
    fn before_tick(&mut self, _n: u64, _ctl: &Controller, _board: &mut B) -> bool {
        true
    }
    /// The estimate of a request (the runner's estimator).
    fn estimate(
        &mut self,
        req: &EstimateRequest,
        board: &B,
    ) -> Result<EstimateResult, EstimateError>;
    /// A controller event, in order, with the board as it is when the event is read.
    fn event(&mut self, _ev: Event, _board: &B) {}
    /// After tick `n`, its estimate ([`Timing::Immediate`]) and its events; before the board
    /// advances.
    fn after_tick(&mut self, _n: u64, _out: &TickOutput, _ctl: &Controller, _board: &B) {}
    /// After the board advanced (read the plant's events here).
    fn after_advance(&mut self, _board: &mut B) {}
}

/// How a run ended.
#[derive(Clone, Copy, Debug)]
pub struct RunEnd {
    /// Ticks run.
    pub ticks: u64,
    /// The controller held, was done or faulted (by the [`Timing`]'s reading).
    pub finished: bool,
    /// The last tick's output.
    pub last: Option<TickOutput>,
}

/// Holding, done or faulted: the run can end.
pub const fn finished(state: State) -> bool {
    matches!(state, State::Holding | State::Done | State::Fault(_))
}

/// Runs `ctl` on `board` within `limits`, telling `obs` what happens.
pub fn run<B: Board, O: Observer<B>>(
    ctl: &mut Controller,
    board: &mut B,
    limits: Limits,
    obs: &mut O,
) -> RunEnd {
    let mut end = RunEnd {
        ticks: 0,
        finished: false,
        last: None,
    };
    let mut stop_at: Option<u64> = None;
    for n in 0..limits.max_ticks {
        if !obs.before_tick(n, ctl, board) {
            break;
        }
        let out = grasp::tick_dyn(ctl, board);
        end.ticks = n + 1;
        end.last = Some(out);
        if limits.timing == Timing::Immediate {
            deliver(ctl, board, &out, obs);
        }
        drain_events(ctl, board, obs);
        obs.after_tick(n, &out, ctl, board);
        board.advance();
        obs.after_advance(board);
        let state = match limits.timing {
            Timing::Immediate => ctl.state(),
            Timing::Firmware => {
                deliver(ctl, board, &out, obs);
                drain_events(ctl, board, obs);
                out.state
            }
        };
        end.finished = finished(state);
        if end.finished && stop_at.is_none() {
            stop_at = limits.extra_ticks.map(|x| n.saturating_add(x));
        }
        if stop_at.is_some_and(|s| n >= s) {
            break;
        }
    }
    end
}

/// The estimate of a request that `out` reported ready, delivered.
fn deliver<B: Board, O: Observer<B>>(
    ctl: &mut Controller,
    board: &mut B,
    out: &TickOutput,
    obs: &mut O,
) {
    if !out.estimate_ready {
        return;
    }
    if let Some(req) = ctl.take_request() {
        let r = obs.estimate(&req, board);
        ctl.deliver(board, r);
    }
}

fn drain_events<B: Board, O: Observer<B>>(ctl: &mut Controller, board: &B, obs: &mut O) {
    while let Some(ev) = ctl.poll_event() {
        obs.event(ev, board);
    }
}
