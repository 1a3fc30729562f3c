//! The RTIC application of device mode (feature `device`, board or QEMU): the tasks of
//! `app.rs` (same priorities, controller path and watchdog supervision) plus the host link, so
//! one power-up runs many grasps.
//!
//! | prio | task        | kind                           | work                                            |
//! |------|-------------|--------------------------------|-------------------------------------------------|
//! | 4    | `sample`    | hardware, `ADC`, 10 kHz        | as in `app.rs` while a grasp runs; bridge off while halted; the host's silence checked; the watchdog fed |
//! | 3    | `supervise` | software                       | the grasp state machine                         |
//! | 2    | `estimate`  | software                       | the estimator the grasp's settings name         |
//! | 1    | `link_rx`   | hardware, `OTG_FS` (board: USB; QEMU: UART0 RX) | service the link, decode requests, answer them; encode and send what is queued for the host; stop switches the bridge off at once; a closed link stops a grasp in motion |
//! | 1    | `host`      | software                       | events, contacts and samples queued for the host (and defmt); pends `link_rx` |
//!
//! A grasp starts from a fresh controller (`Controller::new` with the host's settings); on QEMU
//! also from a fresh simulated finger at its rest pose: the same start as a power-up grasp, so
//! its estimate equals the host runner's with the same scene and settings.

#[cfg_attr(
    feature = "qemu",
    rtic::app(
        device = crate::sim::pac,
        dispatchers = [UART1TX, UART2RX, UART2TX],
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
    use proto::{
        Command, DeviceMsg, DeviceState, Error, Event, EventKind, FrameError, ParamId, Reply,
        Request, StoreFailure, Unsupported, VERSION,
    };
    use rtic::mutex::prelude::*;
    use rtic_sync::channel::{Receiver, Sender};
    use rtic_sync::make_channel;
    use settings::LoadStatus;

    use crate::ctl;
    use crate::device::{
        self, Device, Transport, ACTIVE, HALT, HOST_LOST, LAST_RX_TICK, SWEEPING, SWEEP_ROWS,
    };
    use crate::fault::supervision;
    use crate::platform::{self, Board};
    use crate::telemetry::{self as tm, Msg, QUEUE};

    #[shared]
    struct Shared {
        link: Link,
        sup: Supervisor,
        lp: ControlLoop,
        board: Board,
        dev: Device,
        store: Option<crate::settings_flash::Settings>,
    }

    #[local]
    struct Local {
        tel_tx: Sender<'static, Msg, QUEUE>,
        sup_tx: Sender<'static, Msg, QUEUE>,
        est_tx: Sender<'static, Msg, QUEUE>,
        table: Option<&'static ctl::EstimatorTable>,
        finger: pts::Finger,
    }

    #[init(local = [
        table_store: ctl::TableSlot = ctl::TableSlot::Empty,
        link_store: platform::LinkStore = platform::LinkStore::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let (tel_tx, tel_rx) = make_channel!(Msg, QUEUE);
        #[cfg(feature = "qemu")]
        let (board, cfg) = platform::init(cx.core);
        #[cfg(not(feature = "qemu"))]
        let (board, cfg, usb) = platform::init(cx.core, cx.device);
        defmt::info!(
            "BOOT finger={=str} l2_um={=u32} scene={=str} board={=str} dt_us={=u32} mode=device",
            crate::config::FINGER_NAME,
            (crate::config::FINGER.l2 * 1e6) as u32,
            crate::config::SCENE,
            platform::NAME,
            (cfg.drive.dt_s * 1e6) as u32
        );
        crate::fault::latch::check_at_boot();
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
        let boot = crate::settings_flash::boot();
        #[cfg(feature = "qemu")]
        let io = platform::open_link(cx.local.link_store);
        #[cfg(not(feature = "qemu"))]
        let io = platform::open_link(cx.local.link_store, usb);
        let mut dev = Device::new(crate::config::SCENE, io);
        match boot
            .status
            .map_err(|_| StoreFailure::Flash)
            .and_then(|st| decoded(st, &boot.payload))
        {
            Ok(s) => {
                dev.settings = s;
                dev.source = proto::SettingsSource::Store;
                dev.estimator = s.estimator;
                device::set_decimation(s.telemetry_hz);
                defmt::info!(
                    "SETTINGS source=store dta_unm={=i32}",
                    (s.delta_ta_nm * 1e6) as i32
                );
            }
            Err(why) => {
                dev.source = proto::SettingsSource::Defaults { why };
                defmt::warn!("SETTINGS source=defaults ({=str})", failure_name(why))
            }
        }
        host::spawn(tel_rx).ok();
        let mut board = board;
        board.start_watchdog();
        defmt::info!(
            "DEVICE ready: waiting for the host on {=str}",
            platform::LINK_NAME
        );
        (
            Shared {
                link,
                sup,
                lp,
                board,
                dev,
                store: boot.settings,
            },
            Local {
                sup_tx: tel_tx.clone(),
                est_tx: tel_tx.clone(),
                tel_tx,
                table,
                finger: cfg.finger,
            },
        )
    }

    #[idle]
    fn idle(_cx: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// The sampling + torque loop, 10 kHz, as in `app.rs` while a grasp runs.
    #[task(binds = ADC, priority = 4, shared = [link, lp, board], local = [tel_tx, last_state: State = State::Init, rest_sent: bool = false])]
    fn sample(cx: sample::Context) {
        let t0 = platform::stamp();
        let tel = cx.local.tel_tx;
        let tick = tm::TICKS.fetch_add(1, Ordering::Relaxed) + 1;
        crate::fault::inject(tick);
        (cx.shared.link, cx.shared.lp, cx.shared.board).lock(|l, lp, board| {
            board.ack_sample();
            if HALT.load(Ordering::Relaxed) {
                if !board.is_safe() {
                    lp.stop(board);
                }
            } else {
                let out = lp.tick(board, l);
                let state = l.state;
                let input = l.has_input();
                let sweep = lp.sweep_phase();
                if let Some(phase) = sweep {
                    let record = lp.sweep_record();
                    sweep_tick(tel, tick, &out, record, phase, board.raw());
                }
                tm::record_work(tick, platform::stamp().wrapping_sub(t0));
                // Each grasp's rest check, once it is over (a new grasp has no report yet).
                match (lp.rest_report(), *cx.local.rest_sent) {
                    (Some(r), false) => {
                        *cx.local.rest_sent = true;
                        send(tel, Msg::Rest(r));
                    }
                    (None, true) => *cx.local.rest_sent = false,
                    _ => {}
                }
                if input && supervise::spawn().is_err() {
                    tm::SUP_BUSY.fetch_add(1, Ordering::Relaxed);
                }
                // A silent host in the middle of a grasp: bridge off, reported.
                let silent = tick.wrapping_sub(LAST_RX_TICK.load(Ordering::Relaxed));
                let moving = device::in_motion(state) || SWEEPING.load(Ordering::Relaxed);
                if moving && silent > device::HOST_TIMEOUT_TICKS {
                    HALT.store(true, Ordering::SeqCst);
                    ACTIVE.store(false, Ordering::SeqCst);
                    HOST_LOST.store(true, Ordering::SeqCst);
                    lp.stop(board);
                    send(
                        tel,
                        Msg::HostLost {
                            tick,
                            silent_ticks: silent,
                        },
                    );
                }
                if state == State::Estimating && *cx.local.last_state != State::Estimating {
                    if let Some(t) = board.truth("settled") {
                        send(tel, Msg::Truth(t));
                    }
                }
                *cx.local.last_state = state;
                let dec = device::DECIMATION.load(Ordering::Relaxed);
                if sweep.is_none() && dec > 0 && tick % dec == 0 && !tel.is_full() {
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
            // The watchdog, as in `app.rs`: fed while this loop runs and the supervisor has
            // checked in recently, whether or not a grasp runs.
            if supervision::may_feed(tick) {
                board.feed_watchdog();
            }
        });
        if tick % supervision::SUP_HEARTBEAT_TICKS == 0 {
            let _ = supervise::spawn();
        }
        platform::rearm_sampling();
        tm::PREEMPT.fetch_add(platform::stamp().wrapping_sub(t0), Ordering::Relaxed);
    }

    /// A sweep's tick: its row to the host when it records one, and its end (bridge already
    /// off) once, unless the host ended it first.
    fn sweep_tick(
        tel: &mut Sender<'static, Msg, QUEUE>,
        tick: u32,
        out: &grasp::LoopOutput,
        record: bool,
        phase: grasp::calibrate::Phase,
        (encoder_count, current_code): (u16, u16),
    ) {
        if record && SWEEPING.load(Ordering::Relaxed) {
            SWEEP_ROWS.fetch_add(1, Ordering::Relaxed);
            send(
                tel,
                Msg::SweepRow(proto::Sample {
                    tick,
                    theta_a_urad: out.theta_a_urad,
                    torque_unm: out.torque_unm,
                    torque_ref_unm: out.torque_ref_unm,
                    duty: out.duty,
                    state: DeviceState::Sweeping,
                    encoder_count,
                    current_code,
                }),
            );
        }
        if let Some(end) = device::sweep_end(phase) {
            if SWEEPING.swap(false, Ordering::SeqCst) {
                HALT.store(true, Ordering::SeqCst);
                ACTIVE.store(false, Ordering::SeqCst);
                let rows = SWEEP_ROWS.load(Ordering::Relaxed);
                send(tel, Msg::SweepEnd { tick, end, rows });
            }
        }
    }

    fn send(tel: &mut Sender<'static, Msg, QUEUE>, msg: Msg) {
        if tel.try_send(msg).is_err() {
            tm::dropped();
        }
    }

    /// The grasp state machine (as in `app.rs`).
    #[task(priority = 3, shared = [link, sup], local = [sup_tx])]
    async fn supervise(cx: supervise::Context) {
        let mut link = cx.shared.link;
        let mut sup = cx.shared.sup;
        let tel = cx.local.sup_tx;
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
        supervision::supervisor_check_in(tm::TICKS.load(Ordering::Relaxed));
    }

    /// The estimate with the estimator the grasp's settings named.
    #[task(
        priority = 2,
        shared = [sup, link],
        local = [est_tx, table, finger, req: grasp::EstimateRequest = grasp::EstimateRequest::EMPTY]
    )]
    async fn estimate(cx: estimate::Context) {
        let mut sup = cx.shared.sup;
        let mut link = cx.shared.link;
        // Into the task's static slot: one copy of the samples taken, not three of the
        // whole 3 KiB request.
        let req = cx.local.req;
        if !sup.lock(|s| s.take_request_into(req)) {
            return;
        }
        let result = ctl::run_estimate_as(cx.local.finger, req, *cx.local.table);
        // Events before the state is published (as in `supervise`): the END the loop sends
        // once it sees Holding or a fault must not overtake them in the telemetry queue.
        sup.lock(|s| s.deliver(result));
        while let Some(ev) = sup.lock(|s| s.poll_event()) {
            send(cx.local.est_tx, Msg::Event(ev));
        }
        (&mut sup, &mut link).lock(|s, l| s.publish(l));
    }

    /// Everything the tasks report: defmt (events, plant, truth) and the host (events,
    /// contacts, samples).
    #[task(priority = 1, shared = [dev])]
    async fn host(mut cx: host::Context, mut rx: Receiver<'static, Msg, QUEUE>) {
        while let Ok(msg) = rx.recv().await {
            if !matches!(msg, Msg::Sample { .. } | Msg::SweepRow(_)) {
                tm::log(&msg);
            }
            cx.shared.dev.lock(|d| match msg {
                Msg::Sample {
                    tick,
                    theta_a_urad,
                    torque_unm,
                    torque_ref_unm,
                    duty,
                    state,
                    raw: (encoder_count, current_code),
                } => d.sample(proto::Sample {
                    tick,
                    theta_a_urad,
                    torque_unm,
                    torque_ref_unm,
                    duty,
                    state: device::state(state),
                    encoder_count,
                    current_code,
                }),
                Msg::Event(ev) => d.event(&ev),
                Msg::SweepRow(s) => d.sample(s),
                Msg::SweepEnd { tick, end, rows } => d.sweep_ended(tick, end, rows),
                Msg::HostLost { tick, silent_ticks } => {
                    d.sweep_stopped(tick);
                    let f = device::host_lost(silent_ticks);
                    d.send(DeviceMsg::Event(Event {
                        tick,
                        kind: EventKind::Fault(f),
                    }));
                }
                _ => {}
            });
            // The link's task encodes and sends: it runs when this one yields.
            pend_link();
        }
    }

    /// Makes the host link's interrupt run ([`Device::flush`] at the end of [`receive`]).
    fn pend_link() {
        #[cfg(feature = "qemu")]
        rtic::pend(crate::sim::pac::Interrupt::OTG_FS);
        #[cfg(not(feature = "qemu"))]
        rtic::pend(stm32f4xx_hal::pac::Interrupt::OTG_FS);
    }

    /// The host link's interrupt: USB events and bytes on the board (OTG FS), received bytes on
    /// QEMU (UART0, whose line src/sim/pac.rs names `OTG_FS` too). Below the loop, the
    /// supervisor and the estimate, so host traffic never delays them.
    #[task(binds = OTG_FS, priority = 1, shared = [dev, lp, board, link, sup, store], local = [was_open: bool = false])]
    fn link_rx(cx: link_rx::Context) {
        receive(&mut { cx.shared }, cx.local.was_open);
    }

    /// The shared resources of the receive task.
    type Rx<'a> = link_rx::SharedResources<'a>;

    /// Bytes from the host: decoded into requests, each answered. A link that closes while a
    /// grasp is in motion stops it (`was_open`: the link's state at the last call).
    fn receive(sh: &mut Rx<'_>, was_open: &mut bool) {
        loop {
            let mut buf = [0u8; 64];
            let (n, open) = sh.dev.lock(|d| (d.io.read(&mut buf), d.io.open()));
            if open != *was_open {
                *was_open = open;
                if open {
                    defmt::info!("HOST link open");
                    // A new host starts with a new frame.
                    sh.dev.lock(|d| d.rx = proto::Decoder::new());
                } else {
                    defmt::warn!("HOST link closed");
                    link_closed(sh);
                }
            }
            if n == 0 {
                break;
            }
            for &b in buf.get(..n).unwrap_or(&[]) {
                let r = sh.dev.lock(|d| d.rx.push(b));
                if let Some(r) = r {
                    LAST_RX_TICK.store(tm::TICKS.load(Ordering::Relaxed), Ordering::Relaxed);
                    handle(sh, r);
                    // Each reply out before the next request: a burst of requests cannot
                    // fill the message queue with replies.
                    sh.dev.lock(|d| d.flush());
                }
            }
        }
        sh.dev.lock(|d| d.flush());
    }

    /// The host let go of the link (USB: port closed, cable pulled, bus suspended): a grasp in
    /// motion ends as for a silent host (bridge off, `HostLost` fault until a stop); a finger
    /// holding keeps holding.
    fn link_closed(sh: &mut Rx<'_>) {
        let state = sh.link.lock(|l| l.state);
        let moving = device::in_motion(state) || SWEEPING.load(Ordering::Relaxed);
        if !(ACTIVE.load(Ordering::Relaxed) && moving) {
            return;
        }
        HALT.store(true, Ordering::SeqCst);
        ACTIVE.store(false, Ordering::SeqCst);
        HOST_LOST.store(true, Ordering::SeqCst);
        (&mut sh.lp, &mut sh.board).lock(|lp, board| lp.stop(board));
        let tick = tm::TICKS.load(Ordering::Relaxed);
        let silent = tick.wrapping_sub(LAST_RX_TICK.load(Ordering::Relaxed));
        defmt::warn!(
            "HOST lost at tick {=u32} (link closed mid-grasp): bridge off",
            tick
        );
        sh.dev.lock(|d| {
            d.sweep_stopped(tick);
            d.send(DeviceMsg::Event(Event {
                tick,
                kind: EventKind::Fault(device::host_lost(silent)),
            }))
        });
    }

    fn handle(sh: &mut Rx<'_>, r: Result<Request, FrameError>) {
        let req = match r {
            Ok(req) => req,
            Err(FrameError::UnknownCommand { id, tag }) => {
                sh.dev
                    .lock(|d| d.reply(id, Err(Error::UnknownCommand { tag })));
                return;
            }
            Err(e) => {
                sh.dev.lock(|d| d.reply(0, Err(Error::BadFrame(e))));
                return;
            }
        };
        let id = req.id;
        let reboot = matches!(req.cmd, Command::Reboot);
        let result = command(sh, req.cmd);
        sh.dev.lock(|d| d.reply(id, result));
        if reboot {
            // The acknowledgement out first (bounded: the UART drains or we reset anyway),
            // the bridge off, then a system reset: the RAM store and fault latch survive it.
            sh.dev.lock(|d| {
                for _ in 0..100_000 {
                    d.flush();
                    if d.drained() {
                        break;
                    }
                }
            });
            defmt::info!("REBOOT on command");
            platform::safe_state();
            cortex_m::peripheral::SCB::sys_reset();
        }
    }

    /// The state the host sees: the controller's during a grasp, the device's otherwise.
    fn current(sh: &mut Rx<'_>) -> DeviceState {
        let s = sh.link.lock(|l| l.state);
        sh.dev.lock(|d| d.device_state(s))
    }

    fn command(sh: &mut Rx<'_>, cmd: Command) -> Result<Reply, Error> {
        match cmd {
            Command::Hello { version } => hello(version),
            Command::Stop => {
                stop(sh);
                Ok(Reply::Ack)
            }
            Command::Status => Ok(status(sh)),
            Command::Get(ParamId::Scene) if !cfg!(feature = "qemu") => Err(Error::NotSupported {
                what: Unsupported::Scene,
            }),
            Command::Get(ParamId::Scene) => Ok(sh
                .dev
                .lock(|d| Reply::Param(proto::Param::Scene(d.scene.clone())))),
            Command::Get(id) => sh.dev.lock(|d| {
                d.settings
                    .get(id)
                    .map(Reply::Param)
                    .ok_or(Error::UnknownChoice { param: id })
            }),
            Command::Set(p) => set(sh, p),
            Command::Grasp => {
                idle_or_busy(sh)?;
                start_grasp(sh)
            }
            Command::Release => release(sh),
            Command::Calibrate => {
                idle_or_busy(sh)?;
                start_sweep(sh)
            }
            Command::Store => store(sh),
            Command::Load => load(sh),
            // Answered by `handle`, which resets after the acknowledgement.
            Command::Reboot => Ok(Reply::Ack),
            Command::Drive => drive(sh),
        }
    }

    /// The version exchange: the device's name and version, or a mismatch.
    fn hello(version: u8) -> Result<Reply, Error> {
        if version != VERSION {
            return Err(Error::VersionMismatch {
                host: version,
                device: VERSION,
            });
        }
        Ok(Reply::Hello {
            version: VERSION,
            firmware: proto::Name::try_from(concat!("finger-fw ", env!("CARGO_PKG_VERSION")))
                .unwrap_or_default(),
            board: proto::Name::try_from(platform::NAME).unwrap_or_default(),
        })
    }

    /// Torque off now, from any state; acknowledges a latched fault.
    fn stop(sh: &mut Rx<'_>) {
        let rx_tick = tm::TICKS.load(Ordering::Relaxed);
        HALT.store(true, Ordering::SeqCst);
        ACTIVE.store(false, Ordering::SeqCst);
        (&mut sh.lp, &mut sh.board).lock(|lp, board| lp.stop(board));
        HOST_LOST.store(false, Ordering::SeqCst);
        let off_tick = tm::TICKS.load(Ordering::Relaxed);
        defmt::info!(
            "STOP requested_tick={=u32} off_tick={=u32}",
            rx_tick,
            off_tick
        );
        sh.dev.lock(|d| {
            d.rest = Some(DeviceState::Stopped);
            d.send(DeviceMsg::Event(Event {
                tick: off_tick,
                kind: EventKind::Stopped {
                    requested_tick: rx_tick,
                },
            }));
            d.sweep_stopped(off_tick);
        });
    }

    fn status(sh: &mut Rx<'_>) -> Reply {
        let state = current(sh);
        let bridge_on = !sh.board.lock(|b| b.is_safe());
        sh.dev.lock(|d| {
            Reply::Status(proto::Status {
                state,
                tick: tm::TICKS.load(Ordering::Relaxed),
                grasps: d.grasps,
                settings: d.settings,
                // A real finger has no scene to choose.
                scene: cfg!(feature = "qemu").then(|| d.scene.clone()),
                bridge_on,
                settings_source: d.source,
                settings_changed: d.changed,
            })
        })
    }

    fn set(sh: &mut Rx<'_>, p: proto::Param) -> Result<Reply, Error> {
        // The telemetry rate changes nothing the controller does: settable any time (a
        // recording raises it for one grasp and restores it while holding).
        if !matches!(p, proto::Param::TelemetryHz(_)) {
            idle_or_busy(sh)?;
        }
        if let proto::Param::Scene(name) = &p {
            if !cfg!(feature = "qemu") {
                return Err(Error::NotSupported {
                    what: Unsupported::Scene,
                });
            }
            if plant::scenes::by_name(name.as_str()).is_none() {
                return Err(Error::UnknownChoice {
                    param: ParamId::Scene,
                });
            }
            sh.dev.lock(|d| d.scene = name.clone());
            return Ok(Reply::Ack);
        }
        sh.dev.lock(|d| {
            let avail: heapless::Vec<proto::Estimator, 2> = ctl::AVAILABLE
                .iter()
                .map(|e| ctl::proto_estimator(*e))
                .collect();
            let before = d.settings;
            d.settings.set(&p, &avail)?;
            d.changed |= d.settings != before;
            device::set_decimation(d.settings.telemetry_hz);
            Ok(Reply::Ack)
        })
    }

    /// Holding: the controller lets go and opens the finger (its events follow). In any
    /// other state of a grasp the release is an abort: torque off now.
    fn release(sh: &mut Rx<'_>) -> Result<Reply, Error> {
        let state = current(sh);
        if !ACTIVE.load(Ordering::Relaxed) {
            return Err(Error::Busy { state });
        }
        let released = (&mut sh.sup, &mut sh.link).lock(|s, l| {
            let started = s.release();
            s.publish(l);
            started
        });
        if released {
            return Ok(Reply::Ack);
        }
        HALT.store(true, Ordering::SeqCst);
        ACTIVE.store(false, Ordering::SeqCst);
        (&mut sh.lp, &mut sh.board).lock(|lp, board| lp.stop(board));
        let tick = tm::TICKS.load(Ordering::Relaxed);
        sh.dev.lock(|d| {
            d.sweep_stopped(tick);
            d.rest = Some(DeviceState::Idle);
            d.send(DeviceMsg::Event(Event {
                tick,
                kind: EventKind::Releasing,
            }));
            d.send(DeviceMsg::Event(Event {
                tick,
                kind: EventKind::Idle,
            }));
        });
        Ok(Reply::Ack)
    }

    /// The settings written to the store; never with the bridge on (erasing flash stalls
    /// the CPU on the board).
    fn store(sh: &mut Rx<'_>) -> Result<Reply, Error> {
        idle_or_busy(sh)?;
        if !sh.board.lock(|b| b.is_safe()) {
            return Err(Error::Busy { state: current(sh) });
        }
        let settings = sh.dev.lock(|d| d.settings);
        let mut buf = [0u8; proto::Settings::MAX_BYTES];
        let bytes = settings.to_bytes(&mut buf).map_err(|_| Error::Store {
            why: StoreFailure::Flash,
        })?;
        let r = sh.store.lock(|st| match st {
            Some(st) => st.store(bytes).map_err(|_| StoreFailure::Flash),
            None => Err(StoreFailure::Flash),
        });
        match r {
            Ok(seq) => {
                sh.dev.lock(|d| {
                    d.source = proto::SettingsSource::Store;
                    d.changed = false;
                });
                defmt::info!(
                    "SETTINGS stored sequence={=u32} len={=usize}",
                    seq,
                    bytes.len()
                );
                Ok(Reply::Ack)
            }
            Err(why) => {
                defmt::error!("SETTINGS store failed ({=str})", failure_name(why));
                Err(Error::Store { why })
            }
        }
    }

    /// The stored settings loaded and checked, replacing the current ones.
    fn load(sh: &mut Rx<'_>) -> Result<Reply, Error> {
        idle_or_busy(sh)?;
        let mut buf = [0u8; crate::settings_flash::MAX_PAYLOAD];
        let r = sh.store.lock(|st| match st {
            Some(st) => st
                .load(&mut buf)
                .map_err(|_| StoreFailure::Flash)
                .and_then(|status| match status.payload(&buf) {
                    Some(p) => decoded(status, p),
                    None => decoded(status, &[]),
                }),
            None => Err(StoreFailure::Flash),
        });
        match r {
            Ok(s) => {
                sh.dev.lock(|d| {
                    d.settings = s;
                    d.source = proto::SettingsSource::Store;
                    d.changed = false;
                });
                device::set_decimation(s.telemetry_hz);
                defmt::info!(
                    "SETTINGS source=store dta_unm={=i32}",
                    (s.delta_ta_nm * 1e6) as i32
                );
                Ok(Reply::Ack)
            }
            Err(why) => {
                defmt::warn!("SETTINGS load failed ({=str})", failure_name(why));
                Err(Error::Store { why })
            }
        }
    }

    /// The drive constants the host needs to read a recording: the selected scene's in QEMU,
    /// the board's build finger otherwise.
    fn drive(sh: &mut Rx<'_>) -> Result<Reply, Error> {
        #[cfg(feature = "qemu")]
        let drive = {
            let scene_name = sh.dev.lock(|d| d.scene.clone());
            let scene = plant::scenes::by_name(scene_name.as_str())
                .map(ctl::finger_scene)
                .ok_or(Error::UnknownChoice {
                    param: ParamId::Scene,
                })?;
            ctl::scene_drive(&scene)
        };
        #[cfg(not(feature = "qemu"))]
        let drive = {
            let _ = sh;
            ctl::board_drive()
        };
        Ok(Reply::Drive(device::drive(&drive)))
    }

    /// The settings a load found, checked (range, and an estimator this build has).
    fn decoded(status: LoadStatus, payload: &[u8]) -> Result<proto::Settings, StoreFailure> {
        match status {
            LoadStatus::Loaded { .. } => {}
            LoadStatus::Empty => return Err(StoreFailure::Empty),
            LoadStatus::Corrupt { .. } => return Err(StoreFailure::Corrupt),
            LoadStatus::Foreign { .. } => return Err(StoreFailure::Foreign),
        }
        let s = proto::Settings::from_bytes(payload).map_err(|_| StoreFailure::Invalid)?;
        if ctl::AVAILABLE
            .iter()
            .any(|e| ctl::proto_estimator(*e) == s.estimator)
        {
            Ok(s)
        } else {
            Err(StoreFailure::Invalid)
        }
    }

    /// A store failure in words, for the log.
    fn failure_name(why: StoreFailure) -> &'static str {
        match why {
            StoreFailure::Empty => "empty store",
            StoreFailure::Corrupt => "corrupt store",
            StoreFailure::Foreign => "foreign settings layout",
            StoreFailure::Invalid => "stored settings invalid for this build",
            StoreFailure::Flash => "flash error",
        }
    }

    /// Ok when no grasp runs and no fault is latched.
    fn idle_or_busy(sh: &mut Rx<'_>) -> Result<(), Error> {
        let state = current(sh);
        match state {
            DeviceState::Fault(fault) => Err(Error::FaultLatched { fault }),
            _ if ACTIVE.load(Ordering::Relaxed) => Err(Error::Busy { state }),
            _ => Ok(()),
        }
    }

    /// The simulated finger a run starts on (QEMU); the board has none to replace.
    #[cfg(feature = "qemu")]
    type FreshPlant = plant::Plant;
    #[cfg(not(feature = "qemu"))]
    type FreshPlant = core::convert::Infallible;

    /// What the next grasp or sweep runs with: the controller configuration from the settings
    /// and the drive, and on QEMU a fresh finger at rest in the selected scene (its object
    /// taken away for a sweep: it must be free). On the board: the real finger where it is.
    fn next_run(
        sh: &mut Rx<'_>,
        free: bool,
    ) -> Result<(grasp::ControllerConfig, Option<FreshPlant>), Error> {
        let (settings, scene_name) = sh.dev.lock(|d| (d.settings, d.scene.clone()));
        #[cfg(feature = "qemu")]
        {
            let unknown = || Error::UnknownChoice {
                param: ParamId::Scene,
            };
            let mut scene = plant::scenes::by_name(scene_name.as_str())
                .map(ctl::finger_scene)
                .ok_or_else(unknown)?;
            let cfg = if free {
                scene.object = plant::scene::ObjectSpec::None;
                ctl::config_with(ctl::scene_drive(&scene), &settings)
            } else {
                ctl::with_scene_rest_check(
                    ctl::config_with(ctl::scene_drive(&scene), &settings),
                    &scene,
                )
            };
            let plant = plant::Plant::new(&scene).map_err(|_| unknown())?;
            Ok((cfg, Some(plant)))
        }
        #[cfg(not(feature = "qemu"))]
        {
            let _ = (&scene_name, free);
            Ok((ctl::config_with(ctl::board_drive(), &settings), None))
        }
    }

    /// Puts a new loop, link and supervisor in place (and on QEMU the fresh finger) with the
    /// bridge enabled from the next tick; returns the tick before it. Read inside the lock
    /// (the sampling task cannot run meanwhile): a recording of the run starts at `tick + 1`.
    fn install(
        sh: &mut Rx<'_>,
        (lp_new, link_new, sup_new): (ControlLoop, Link, Supervisor),
        plant: Option<FreshPlant>,
        sweeping: bool,
    ) -> u32 {
        (&mut sh.lp, &mut sh.board, &mut sh.link, &mut sh.sup).lock(|lp, board, link, sup| {
            let tick = tm::TICKS.load(Ordering::Relaxed);
            LAST_RX_TICK.store(tick, Ordering::Relaxed);
            *lp = lp_new;
            *link = link_new;
            *sup = sup_new;
            #[cfg(feature = "qemu")]
            if let Some(p) = plant {
                board.reset_plant(p);
            }
            #[cfg(not(feature = "qemu"))]
            let _ = (board, plant);
            HOST_LOST.store(false, Ordering::SeqCst);
            SWEEP_ROWS.store(0, Ordering::Relaxed);
            SWEEPING.store(sweeping, Ordering::SeqCst);
            ACTIVE.store(true, Ordering::SeqCst);
            HALT.store(false, Ordering::SeqCst);
            tick
        })
    }

    /// The calibration sweep: a sweep loop with the settings' drive on the free finger, and a
    /// fresh supervisor that only hears the loop's faults.
    fn start_sweep(sh: &mut Rx<'_>) -> Result<Reply, Error> {
        let (cfg, plant) = next_run(sh, true)?;
        let params = ctl::params(&cfg).map_err(|_| Error::ConfigRejected)?;
        let sweep = grasp::calibrate::Sweep::new(grasp::calibrate::SweepConfig::DEFAULT)
            .map_err(|_| Error::ConfigRejected)?;
        let (_, link, sup) = ctl::controller(cfg)
            .map_err(|_| Error::ConfigRejected)?
            .into_parts();
        let lp = ControlLoop::for_sweep(&params, sweep);
        let tick = install(sh, (lp, link, sup), plant, true);
        defmt::info!("SWEEP started at tick {=u32}", tick);
        sh.dev.lock(|d| {
            d.rest = Some(DeviceState::Sweeping);
            d.send(DeviceMsg::Event(Event {
                tick,
                kind: EventKind::SweepStarted,
            }));
        });
        Ok(Reply::Ack)
    }

    /// A fresh controller with the settings (QEMU: and a fresh finger at rest in the selected
    /// scene; board: the real finger where it is, the build's drive constants).
    fn start_grasp(sh: &mut Rx<'_>) -> Result<Reply, Error> {
        let settings = sh.dev.lock(|d| d.settings);
        let (cfg, plant) = next_run(sh, false)?;
        let ctrl = ctl::controller(cfg).map_err(|_| Error::ConfigRejected)?;
        let tick = install(sh, ctrl.into_parts(), plant, false);
        sh.dev.lock(|d| {
            d.grasps = d.grasps.wrapping_add(1);
            d.estimator = settings.estimator;
            d.rest = None;
            defmt::info!(
                "GRASP {=u16} scene={=str} dta_unm={=i32} estimator={=str}",
                d.grasps,
                d.scene.as_str(),
                (settings.delta_ta_nm * 1e6) as i32,
                match settings.estimator {
                    proto::Estimator::TwoPoint => "two-point",
                    proto::Estimator::PathFit => "path-fit",
                }
            );
            d.send(DeviceMsg::Event(Event {
                tick,
                kind: EventKind::GraspStarted { grasp: d.grasps },
            }));
        });
        Ok(Reply::Ack)
    }
}
