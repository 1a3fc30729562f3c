//! The RTIC application: four priorities, one job each.
//!
//! | prio | task        | kind                         | work                                             |
//! |------|-------------|------------------------------|--------------------------------------------------|
//! | 4    | `sample`    | hardware, `ADC` line, 10 kHz | read encoder + current, `ControlLoop::tick` (torque loop, fast faults), set the duty; decimated samples |
//! | 3    | `supervise` | software (async)             | `Supervisor::handle` on what the loop handed over (the grasp state machine, once per 4 ms sample), forward events |
//! | 2    | `estimate`  | software (async)             | `take_request_into`, `run_estimate`, `deliver`   |
//! | 1    | `telemetry` | software (async)             | defmt: every event, θa/T_a/state decimated to 50 Hz |
//!
//! Supervision: the loop drives only on a setpoint the supervisor stamped within
//! `LINK_SAMPLES` samples (grasp), and the watchdog (started at the end of `init`) is fed
//! by `sample` only while `supervise` has checked in recently ([`crate::fault::supervision`]).
//!
//! The loop and the state machine meet only in the [`grasp::Link`]: the loop leaves sample
//! sums there and applies the setpoint it finds; the supervisor takes the sums and writes the
//! setpoint. Every lock of it is a copy of a few words, so the 10 kHz task never waits for the
//! state machine's bursts (contact detection scans its history) or for the estimate. Producers
//! of telemetry only `try_send` and count what a full queue drops.

#[cfg_attr(
    feature = "qemu",
    rtic::app(
        device = crate::sim::pac,
        dispatchers = [UART0TX, UART1RX, UART1TX],
        peripherals = false
    )
)]
#[cfg_attr(
    not(feature = "qemu"),
    rtic::app(
        device = stm32f4xx_hal::pac,
        dispatchers = [SPI2, SPI3, SPI4],
        peripherals = true
    )
)]
mod app {
    use core::sync::atomic::Ordering;

    use grasp::{ControlLoop, Link, State, Supervisor};
    use rtic_sync::channel::{Receiver, Sender};
    use rtic_sync::make_channel;

    use crate::ctl;
    use crate::fault::supervision;
    use crate::platform::{self, Board};
    use crate::telemetry::{self as tm, Done, Msg, QUEUE};

    #[shared]
    struct Shared {
        link: Link,
        sup: Supervisor,
    }

    #[local]
    struct Local {
        lp: ControlLoop,
        board: Board,
        tel_tx: Sender<'static, Msg, QUEUE>,
        sup_tx: Sender<'static, Msg, QUEUE>,
        est_tx: Sender<'static, Msg, QUEUE>,
        /// The estimator's table (built in `init`; `None` when the finger is outside its formats).
        table: Option<&'static ctl::EstimatorTable>,
        /// The finger the estimate inverts (the controller's).
        finger: pts::Finger,
        decimation: u32,
    }

    #[init(local = [table_store: ctl::TableSlot = ctl::TableSlot::Empty])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let init0 = platform::stamp();
        let (tel_tx, tel_rx) = make_channel!(Msg, QUEUE);
        #[cfg(feature = "qemu")]
        let (board, cfg) = platform::init(cx.core);
        #[cfg(not(feature = "qemu"))]
        let (board, cfg) = platform::init(cx.core, cx.device);
        defmt::info!(
            "BOOT finger={=str} l2_um={=u32} scene={=str} board={=str} dt_us={=u32} estimator={=str} dta_unm={=i32}",
            crate::config::FINGER_NAME,
            (crate::config::FINGER.l2 * 1e6) as u32,
            crate::config::SCENE,
            platform::NAME,
            (cfg.drive.dt_s * 1e6) as u32,
            match ctl::ESTIMATOR {
                grasp::Estimator::TwoPoint => "two-point",
                grasp::Estimator::PathFit => "path-fit",
            },
            (ctl::DELTA_TA_NM * 1e6) as i32
        );
        crate::fault::latch::check_at_boot();
        // The stored settings (issue 18): loaded once, the status logged; the build's
        // defaults apply unless it is Loaded.
        let _settings = crate::settings_flash::boot();
        let decimation = ctl::decimation(&cfg.drive);
        // Calibration of the work counter: `delay(n)` is n + 1 passes of `subs; bne`, i.e.
        // 200 002 instructions (QEMU icount: stamps × 40; board: CPU cycles of that loop).
        let c0 = platform::stamp();
        cortex_m::asm::delay(100_000);
        defmt::info!(
            "CAL instructions=200002 stamps={=u32}",
            platform::stamp().wrapping_sub(c0)
        );
        let ctrl = match ctl::controller(cfg) {
            Ok(c) => c,
            Err(_) => {
                defmt::error!("CONFIG rejected by grasp: bridge stays off");
                platform::safe_state();
                platform::halt(4)
            }
        };
        cx.local
            .table_store
            .fill(ctl::estimator_table(&cfg.finger, &cfg.drive));
        let table = cx.local.table_store.get();
        let (lp, link, sup) = ctrl.into_parts();
        telemetry::spawn(tel_rx).ok();
        // The watchdog starts last: init's long work (calibration loop, the path fit's table)
        // runs before it, so only the window from here to the first feed counts.
        let mut board = board;
        board.start_watchdog();
        defmt::info!(
            "INIT stamps={=u32} (watchdog started at its end)",
            platform::stamp().wrapping_sub(init0)
        );
        (
            Shared { link, sup },
            Local {
                lp,
                board,
                sup_tx: tel_tx.clone(),
                est_tx: tel_tx.clone(),
                table,
                finger: cfg.finger,
                tel_tx,
                decimation,
            },
        )
    }

    /// Sleep between interrupts (on QEMU with `-icount sleep=off` the virtual clock then jumps
    /// straight to the next SysTick instead of executing an idle loop).
    #[idle]
    fn idle(_cx: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// The sampling + torque loop, 10 kHz (the controller's `dt_s`). Board: the ADC
    /// end-of-conversion of the current sample triggered by the PWM timer in the middle of
    /// every other 20 kHz PWM period. QEMU: the same line, pended by SysTick (src/sim).
    #[task(
        binds = ADC,
        priority = 4,
        shared = [link],
        local = [lp, board, tel_tx, decimation, rest_logged: bool = false, done: bool = false, end: Option<Done> = None, last_state: State = State::Init, fed: bool = false]
    )]
    fn sample(cx: sample::Context) {
        let t0 = platform::stamp();
        let tel = cx.local.tel_tx;
        let board = cx.local.board;
        let lp = cx.local.lp;
        let mut link = cx.shared.link;
        board.ack_sample();
        let tick = tm::TICKS.fetch_add(1, Ordering::Relaxed) + 1;
        crate::fault::inject(tick);
        // Highest priority: this lock is free (no other task of this priority).
        let (out, state, input) = link.lock(|l| {
            let out = lp.tick(board, l);
            (out, l.state, l.has_input())
        });
        tm::record_work(tick, platform::stamp().wrapping_sub(t0));
        // Where the finger was at power-up, once the rest check is over.
        if !*cx.local.rest_logged {
            if let Some(r) = lp.rest_report() {
                *cx.local.rest_logged = true;
                send(tel, Msg::Rest(r));
            }
        }
        // Asked again every tick while input waits: a supervisor still running takes it in
        // its loop, else the next tick's spawn starts it.
        if input && supervise::spawn().is_err() {
            tm::SUP_BUSY.fetch_add(1, Ordering::Relaxed);
        }
        // The supervisor's heartbeat: it runs (and checks in) even when the loop has nothing
        // for it (bridge off, end of run), so the watchdog can demand its check-in always.
        if !input && tick % supervision::SUP_HEARTBEAT_TICKS == 0 {
            let _ = supervise::spawn();
        }
        // The watchdog: the loop is alive (this task runs) and so is the supervisor.
        if supervision::may_feed(tick) {
            board.feed_watchdog();
            if !*cx.local.fed {
                *cx.local.fed = true;
                defmt::info!(
                    "WDG first feed, stamps since start={=u32}",
                    board.watchdog_age()
                );
            }
        }
        // The plant's truth once the step has settled (the supervisor has just published it).
        if state == State::Estimating && *cx.local.last_state != State::Estimating {
            if let Some(t) = board.truth("settled") {
                send(tel, Msg::Truth(t));
            }
        }
        *cx.local.last_state = state;
        let finished = ctl::finished(state);
        if tick % *cx.local.decimation == 0 || finished {
            // Samples are best effort: a full queue keeps its room for events.
            if !tel.is_full() {
                let _ = tel.try_send(Msg::Sample {
                    tick,
                    theta_a_urad: out.theta_a_urad,
                    torque_unm: out.torque_unm,
                    torque_ref_unm: out.torque_ref_unm,
                    duty: out.duty,
                    state,
                    raw: board.raw(),
                });
            }
        }
        board.advance();
        while let Some(p) = board.poll_plant_event() {
            send(tel, Msg::Plant(p));
        }
        // The END report, once, when the state machine is through and (for a fault or the
        // end of a release) the loop has switched the bridge off. The loop itself goes on: on
        // the board the finger keeps holding (or stays safe); QEMU exits when the telemetry
        // task has logged it.
        let off_needed = matches!(state, State::Fault(_) | State::Done);
        if finished && !*cx.local.done && (!off_needed || board.is_safe()) {
            // The END report gets out even through a full queue: made once (with the tick the
            // run ended), then offered every tick until the telemetry task has room.
            let end = cx.local.end.get_or_insert_with(|| {
                if let Some(t) = board.truth("end") {
                    send(tel, Msg::Truth(t));
                }
                Done {
                    status: ctl::status(state),
                    state,
                    bridge_safe: board.is_safe(),
                    ticks: tick,
                }
            });
            if tel.try_send(Msg::Done(*end)).is_ok() {
                *cx.local.done = true;
            }
        }
        platform::rearm_sampling();
        tm::PREEMPT.fetch_add(platform::stamp().wrapping_sub(t0), Ordering::Relaxed);
    }

    fn send(tel: &mut Sender<'static, Msg, QUEUE>, msg: Msg) {
        if tel.try_send(msg).is_err() {
            tm::dropped();
        }
    }

    /// The grasp state machine on everything the loop left in the link, then the new
    /// setpoint; its events go to telemetry. Preempted by `sample` only.
    #[task(priority = 3, shared = [link, sup], local = [sup_tx])]
    async fn supervise(cx: supervise::Context) {
        let mut link = cx.shared.link;
        let mut sup = cx.shared.sup;
        let tel = cx.local.sup_tx;
        let t0 = platform::stamp();
        let p0 = tm::PREEMPT.load(Ordering::Relaxed);
        while let Some(input) = link.lock(|l| l.next_input()) {
            let ready = sup.lock(|s| s.handle(input));
            // The events first, then the state: once the loop sees the new state it may
            // report the END, and its message must not overtake the events that led there.
            while let Some(ev) = sup.lock(|s| s.poll_event()) {
                send(tel, Msg::Event(ev));
            }
            // The answer reaches the loop before its next tick.
            (&mut link, &mut sup).lock(|l, s| s.publish(l));
            if ready && estimate::spawn().is_err() {
                tm::dropped();
            }
        }
        let work = platform::stamp()
            .wrapping_sub(t0)
            .wrapping_sub(tm::PREEMPT.load(Ordering::Relaxed).wrapping_sub(p0));
        let _ = tm::record_max(&tm::SUP_WORK_MAX, work);
        supervision::supervisor_check_in(tm::TICKS.load(Ordering::Relaxed));
    }

    /// The estimate: the settled step → `run_estimate` → `deliver`. Preempted by `sample` and
    /// `supervise`.
    #[task(
        priority = 2,
        shared = [sup, link],
        local = [est_tx, table, finger, req: grasp::EstimateRequest = grasp::EstimateRequest::EMPTY]
    )]
    async fn estimate(cx: estimate::Context) {
        let mut sup = cx.shared.sup;
        let mut link = cx.shared.link;
        let t0 = platform::stamp();
        let p0 = tm::PREEMPT.load(Ordering::Relaxed);
        // Into the task's static slot: one copy of the samples taken, not three of the
        // whole 3 KiB request.
        let req = cx.local.req;
        if !sup.lock(|s| s.take_request_into(req)) {
            return;
        }
        let result = ctl::run_estimate(cx.local.finger, req, *cx.local.table);
        let work = platform::stamp()
            .wrapping_sub(t0)
            .wrapping_sub(tm::PREEMPT.load(Ordering::Relaxed).wrapping_sub(p0));
        let _ = tm::record_max(&tm::EST_WORK_MAX, work);
        // Events before the state is published (as in `supervise`): the END the loop sends
        // once it sees Holding or a fault must not overtake them in the telemetry queue.
        sup.lock(|s| s.deliver(result));
        while let Some(ev) = sup.lock(|s| s.poll_event()) {
            send(cx.local.est_tx, Msg::Event(ev));
        }
        (&mut sup, &mut link).lock(|s, l| s.publish(l));
    }

    #[task(priority = 1)]
    async fn telemetry(_cx: telemetry::Context, mut rx: Receiver<'static, Msg, QUEUE>) {
        while let Ok(msg) = rx.recv().await {
            tm::log(&msg);
            if let Msg::Done(done) = msg {
                #[cfg(feature = "qemu")]
                {
                    let (used, size) = crate::fault::stack::high_water();
                    defmt::info!("STACK used={=u32} size={=u32}", used, size);
                }
                platform::finish(done.status);
            }
        }
    }
}
