//! `pts board watch`: θa, T_a, the live K̂c and the state of the device, drawn in the terminal
//! as the samples arrive (ratatui), or one summary line per half second when stdout is not a
//! terminal.
//!
//! [`Watch`] holds what is shown and knows nothing of terminals, so it is tested on its own;
//! [`draw`] renders it into any ratatui backend (a test renders into a `TestBackend`).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use proto::{Command, Contact, DeviceMsg, DeviceState, EventKind, Param, Reply};
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Color, Style};
use ratatui::symbols::Marker;
use ratatui::text::Line;
use ratatui::widgets::{Axis, Block, Chart, Dataset, GraphType, Paragraph};
use ratatui::Frame;

use crate::board::{Board, BoardError};

/// Smallest |θa − θa,c| (rad) over which the live K̂c secant is shown: a few encoder quanta
/// of the paper's drive, so that one count does not swing it.
pub const KC_MIN_DTHETA_RAD: f64 = 2e-3;

/// Events kept for the event pane.
const EVENTS_KEPT: usize = 6;

/// What the watch shows: the last `window_s` seconds of samples, the state, the contact the
/// device detected and its estimate.
#[derive(Clone, Debug)]
pub struct Watch {
    /// Control period of the device (s), for the time axis.
    pub dt_s: f64,
    /// Seconds of samples kept on the charts.
    pub window_s: f64,
    /// (t s, θa rad, T_a N·m, T_ref N·m) of the samples in the window.
    pub samples: VecDeque<(f64, f64, f64, f64)>,
    /// The device's state (from samples and status replies).
    pub state: Option<DeviceState>,
    /// Bridge on, from the last status reply.
    pub bridge_on: Option<bool>,
    /// (θa,c rad, T_a,c N·m) of the contact the device detected in this grasp.
    pub contact: Option<(f64, f64)>,
    /// The estimate the device reported.
    pub estimate: Option<Contact>,
    /// The last events, in words.
    pub events: VecDeque<String>,
    /// Tick of the first sample (the time axis starts there).
    t0_tick: Option<u32>,
}

impl Watch {
    /// An empty watch for a device with control period `dt_s` (s), keeping `window_s` seconds.
    pub fn new(dt_s: f64, window_s: f64) -> Self {
        Watch {
            dt_s,
            window_s,
            samples: VecDeque::new(),
            state: None,
            bridge_on: None,
            contact: None,
            estimate: None,
            events: VecDeque::new(),
            t0_tick: None,
        }
    }

    /// Takes one message from the device.
    pub fn push(&mut self, m: &DeviceMsg) {
        match m {
            DeviceMsg::Sample(s) => {
                let t0 = *self.t0_tick.get_or_insert(s.tick);
                let t = f64::from(s.tick.wrapping_sub(t0)) * self.dt_s;
                self.samples.push_back((
                    t,
                    f64::from(s.theta_a_urad) * 1e-6,
                    f64::from(s.torque_unm) * 1e-6,
                    f64::from(s.torque_ref_unm) * 1e-6,
                ));
                while self
                    .samples
                    .front()
                    .is_some_and(|f| t - f.0 > self.window_s)
                {
                    self.samples.pop_front();
                }
                self.state = Some(s.state);
            }
            DeviceMsg::Event(e) => {
                match e.kind {
                    EventKind::GraspStarted { .. } => {
                        self.contact = None;
                        self.estimate = None;
                    }
                    EventKind::ContactDetected {
                        theta_a_urad,
                        torque_unm,
                    } => {
                        self.contact =
                            Some((f64::from(theta_a_urad) * 1e-6, f64::from(torque_unm) * 1e-6));
                    }
                    _ => {}
                }
                self.events.push_back(event_words(&e.kind));
                while self.events.len() > EVENTS_KEPT {
                    self.events.pop_front();
                }
            }
            DeviceMsg::Contact(c) => self.estimate = Some(*c),
            DeviceMsg::Reply {
                result: Ok(Reply::Status(s)),
                ..
            } => {
                self.state = Some(s.state);
                self.bridge_on = Some(s.bridge_on);
            }
            DeviceMsg::Reply { .. } => {}
        }
    }

    /// The live contact stiffness K̂c (N·m/rad): the secant from the detected contact to the
    /// latest sample, (T_a − T_a,c)/(θa − θa,c), once θa has closed [`KC_MIN_DTHETA_RAD`] past
    /// the contact.
    pub fn kc_live(&self) -> Option<f64> {
        let (thc, tac) = self.contact?;
        let &(_, th, ta, _) = self.samples.back()?;
        // Only once the finger closed past the contact: the impact's bounce (θa back below
        // it) gives a secant of the wrong sign that no contact has.
        let d = th - thc;
        (d >= KC_MIN_DTHETA_RAD).then(|| (ta - tac) / d)
    }

    /// One line for a log: state, θa, T_a, K̂c, the estimate.
    pub fn summary(&self) -> String {
        let state = self.state.map_or("-", |s| s.name());
        let last = self.samples.back();
        let mut s = format!(
            "t {:>7.3} s  state {state:<11} θa {:>9} rad  T_a {:>7} N·m",
            last.map_or(0.0, |x| x.0),
            last.map_or("-".into(), |x| format!("{:.5}", x.1)),
            last.map_or("-".into(), |x| format!("{:.4}", x.2)),
        );
        if let Some(k) = self.kc_live() {
            s += &format!("  K̂c {k:.3} N·m/rad (live)");
        }
        if let Some(c) = &self.estimate {
            s += &format!("  estimate: {}", estimate_words(c));
        }
        s
    }
}

/// An event in words.
pub fn event_words(k: &EventKind) -> String {
    match k {
        EventKind::GraspStarted { grasp } => format!("grasp {grasp} started"),
        EventKind::Calibrated => "current sensor calibrated".into(),
        EventKind::ContactDetected {
            theta_a_urad,
            torque_unm,
        } => format!(
            "contact at θa {:.4} rad, T_a {:.3} N·m",
            f64::from(*theta_a_urad) * 1e-6,
            f64::from(*torque_unm) * 1e-6
        ),
        EventKind::StepDone => "ΔT_a applied".into(),
        EventKind::Settled => "settled".into(),
        EventKind::Estimated => "estimated".into(),
        EventKind::Holding => "holding".into(),
        EventKind::Releasing => "releasing".into(),
        EventKind::Idle => "idle".into(),
        EventKind::Stopped { .. } => "stopped: bridge off".into(),
        EventKind::Fault(f) => format!("fault {:?} (value {}): bridge off", f.kind, f.value),
        EventKind::SweepStarted => "calibration sweep started".into(),
        EventKind::SweepEnded { end, rows } => {
            format!("calibration sweep ended: {} ({rows} rows)", end.name())
        }
    }
}

/// A contact estimate in words: phalanx, k2 with its σ when given, the radius when observed,
/// K̂c, the estimator and the two-point reference when computed beside it.
pub fn estimate_words(c: &Contact) -> String {
    let mm = |um: i32| format!("{:.2}", f64::from(um) / 1000.0);
    let k2 = match (c.k2_um, c.sigma_um) {
        (Some(k), Some(s)) => format!("{} ± {} mm", mm(k), mm(s)),
        (Some(k), None) => format!("{} mm", mm(k)),
        (None, _) => "-".into(),
    };
    let radius = c
        .r_um
        .map_or(String::new(), |r| format!(", R {} mm", mm(r)));
    let reference = c
        .two_point_k2_um
        .map_or(String::new(), |k| format!("; two-point {} mm", mm(k)));
    // The path fit fits no stiffness to a proximal contact and reports K̂c 0.
    let kc = match c.kc_hat_unm_per_rad {
        0 => String::new(),
        k => format!(", K̂c {:.3} N·m/rad", f64::from(k) * 1e-6),
    };
    format!(
        "{:?}, k2 {k2}{radius}{kc} ({:?}{reference})",
        c.phalanx, c.estimator
    )
}

/// (min, max) of a series with a margin, never an empty range.
fn bounds(v: impl Iterator<Item = f64>) -> [f64; 2] {
    let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    });
    if !lo.is_finite() || !hi.is_finite() {
        return [0.0, 1.0];
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    [lo - pad, hi + pad]
}

/// Renders the watch: a header (state, bridge, K̂c, estimate), θa and T_a against time, and
/// the last events.
pub fn draw(f: &mut Frame, w: &Watch) {
    let [head, theta, torque, events] = Layout::vertical([
        Constraint::Length(4),
        Constraint::Percentage(40),
        Constraint::Percentage(40),
        Constraint::Min(3),
    ])
    .areas(f.area());
    let state = w.state.map_or("-", |s| s.name());
    let bridge = match w.bridge_on {
        Some(true) => "on",
        Some(false) => "off",
        None => "-",
    };
    let kc = w
        .kc_live()
        .map_or("-".into(), |k| format!("{k:.3} N·m/rad"));
    let est = w.estimate.as_ref().map_or("-".into(), estimate_words);
    f.render_widget(
        Paragraph::new(vec![
            Line::from(format!(
                "state {state}   bridge {bridge}   K̂c live {kc}   (q: quit)"
            )),
            Line::from(format!("estimate: {est}")),
        ])
        .block(Block::bordered().title(" pts board watch ")),
        head,
    );
    let t = match (w.samples.front(), w.samples.back()) {
        (Some(a), Some(b)) if b.0 > a.0 => [a.0, b.0],
        (Some(a), _) => [a.0, a.0 + 1.0],
        _ => [0.0, 1.0],
    };
    let th: Vec<(f64, f64)> = w.samples.iter().map(|s| (s.0, s.1)).collect();
    let ta: Vec<(f64, f64)> = w.samples.iter().map(|s| (s.0, s.2)).collect();
    let tr: Vec<(f64, f64)> = w.samples.iter().map(|s| (s.0, s.3)).collect();
    let time_axis = |b: [f64; 2]| {
        Axis::default()
            .title("t (s)")
            .bounds(b)
            .labels([format!("{:.2}", b[0]), format!("{:.2}", b[1])])
    };
    let y_axis = |title: &'static str, b: [f64; 2]| {
        Axis::default()
            .title(title)
            .bounds(b)
            .labels([format!("{:.3}", b[0]), format!("{:.3}", b[1])])
    };
    let thb = bounds(th.iter().map(|p| p.1));
    f.render_widget(
        Chart::new(vec![Dataset::default()
            .name("θa")
            .marker(Marker::Braille)
            .graph_type(GraphType::Line)
            .style(Style::default().fg(Color::Cyan))
            .data(&th)])
        .block(Block::bordered().title(" θa (rad) "))
        .x_axis(time_axis(t))
        .y_axis(y_axis("rad", thb)),
        theta,
    );
    let tb = bounds(ta.iter().chain(tr.iter()).map(|p| p.1));
    f.render_widget(
        Chart::new(vec![
            Dataset::default()
                .name("T_a")
                .marker(Marker::Braille)
                .graph_type(GraphType::Line)
                .style(Style::default().fg(Color::Yellow))
                .data(&ta),
            Dataset::default()
                .name("T_ref")
                .marker(Marker::Braille)
                .graph_type(GraphType::Line)
                .style(Style::default().fg(Color::Gray))
                .data(&tr),
        ])
        .block(Block::bordered().title(" T_a and its reference (N·m) "))
        .x_axis(time_axis(t))
        .y_axis(y_axis("N·m", tb)),
        torque,
    );
    let lines: Vec<Line> = w.events.iter().map(|e| Line::from(e.as_str())).collect();
    f.render_widget(
        Paragraph::new(lines).block(Block::bordered().title(" events ")),
        events,
    );
}

/// How long and how fast to watch.
#[derive(Clone, Copy, Debug)]
pub struct WatchOptions {
    /// Start a grasp and stop watching once it ended (holding, a fault, stopped).
    pub grasp: bool,
    /// Stop after this long (s); `None`: until `q` (or the grasp's end with `grasp`).
    pub seconds: Option<f64>,
    /// Telemetry rate during the watch (Hz); the previous rate is restored after.
    pub rate_hz: u16,
    /// Seconds of samples on the charts.
    pub window_s: f64,
    /// Summary lines to stderr (stdout carries JSON).
    pub json: bool,
}

/// Watches the device: in the terminal when `tty`, else one [`Watch::summary`] line every
/// half second on stdout. Returns the final watch.
pub fn run(b: &mut Board, o: &WatchOptions, tty: bool) -> Result<Watch, BoardError> {
    let Reply::Drive(drive) = b.request(Command::Drive)? else {
        return Err(BoardError::Io(
            "the device answered `drive` with another reply".into(),
        ));
    };
    let Reply::Status(status) = b.request(Command::Status)? else {
        return Err(BoardError::Io(
            "the device answered `status` with another reply".into(),
        ));
    };
    b.request(Command::Set(Param::TelemetryHz(o.rate_hz)))?;
    let mut w = Watch::new(drive.dt_s, o.window_s);
    w.push(&DeviceMsg::Reply {
        id: 0,
        result: Ok(Reply::Status(status.clone())),
    });
    let result = if tty {
        let mut term = ratatui::init();
        let r = watch_loop(b, o, &mut w, |w| {
            let _ = term.draw(|f| draw(f, w));
        });
        ratatui::restore();
        r
    } else {
        let mut last = Instant::now();
        watch_loop(b, o, &mut w, |w| {
            if last.elapsed() >= Duration::from_millis(500) {
                if o.json {
                    eprintln!("{}", w.summary());
                } else {
                    println!("{}", w.summary());
                }
                last = Instant::now();
            }
        })
    };
    // The previous rate back whatever happened (the watch's error wins).
    let restored = b.request(Command::Set(Param::TelemetryHz(
        status.settings.telemetry_hz,
    )));
    result?;
    restored?;
    Ok(w)
}

/// Reads, polls the status (the host-alive proof), shows; ends on `q`/Esc/Ctrl-C, the time
/// limit or the grasp's end.
fn watch_loop(
    b: &mut Board,
    o: &WatchOptions,
    w: &mut Watch,
    mut show: impl FnMut(&Watch),
) -> Result<(), BoardError> {
    use ratatui::crossterm::event::{self, Event, KeyCode, KeyModifiers};
    if o.grasp {
        b.request(Command::Grasp)?;
    }
    let t0 = Instant::now();
    let mut last_poll = Instant::now();
    let mut last_draw = Instant::now();
    let mut ended: Option<Instant> = None;
    loop {
        if o.seconds.is_some_and(|s| t0.elapsed().as_secs_f64() >= s) {
            return Ok(());
        }
        // A short linger after the grasp's end so its last samples and estimate show.
        if ended.is_some_and(|t| t.elapsed() >= Duration::from_millis(300)) {
            show(w);
            return Ok(());
        }
        if last_poll.elapsed() >= crate::board::POLL {
            b.send(Command::Status)?;
            last_poll = Instant::now();
        }
        for m in b.poll()? {
            let m = m.map_err(BoardError::Frame)?;
            if let DeviceMsg::Reply { result: Err(e), .. } = &m {
                return Err(BoardError::Device(e.clone()));
            }
            if let DeviceMsg::Event(e) = &m {
                let done = matches!(
                    e.kind,
                    EventKind::Holding | EventKind::Fault(_) | EventKind::Stopped { .. }
                );
                if o.grasp && done && ended.is_none() {
                    ended = Some(Instant::now());
                }
            }
            w.push(&m);
        }
        if last_draw.elapsed() >= Duration::from_millis(50) {
            show(w);
            last_draw = Instant::now();
        }
        if ratatui::crossterm::terminal::is_raw_mode_enabled().unwrap_or(false)
            && event::poll(Duration::ZERO).unwrap_or(false)
        {
            if let Ok(Event::Key(k)) = event::read() {
                let ctrl_c =
                    k.code == KeyCode::Char('c') && k.modifiers.contains(KeyModifiers::CONTROL);
                if ctrl_c || matches!(k.code, KeyCode::Char('q') | KeyCode::Esc) {
                    return Ok(());
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::{Event, Sample};

    fn sample(tick: u32, theta_urad: i32, torque_unm: i32) -> DeviceMsg {
        DeviceMsg::Sample(Sample {
            tick,
            theta_a_urad: theta_urad,
            torque_unm,
            torque_ref_unm: torque_unm + 10_000,
            duty: 0,
            state: DeviceState::Step,
            encoder_count: 0,
            current_code: 2048,
        })
    }

    fn event(kind: EventKind) -> DeviceMsg {
        DeviceMsg::Event(Event { tick: 1, kind })
    }

    /// The live K̂c is the secant from the detected contact, by hand: (0.7 − 0.4)/(−0.15 −
    /// (−0.22)) = 4.2857 N·m/rad; none before θa moved past the threshold or without a contact.
    #[test]
    fn live_kc_is_the_secant_from_the_contact() {
        let mut w = Watch::new(1e-4, 2.0);
        w.push(&sample(10, -220_000, 400_000));
        assert_eq!(w.kc_live(), None, "no contact yet");
        w.push(&event(EventKind::ContactDetected {
            theta_a_urad: -220_000,
            torque_unm: 400_000,
        }));
        w.push(&sample(11, -219_500, 500_000));
        assert_eq!(w.kc_live(), None, "0.5 mrad is below the threshold");
        w.push(&sample(12, -150_000, 700_000));
        let k = w.kc_live().unwrap();
        assert!((k - 0.3 / 0.07).abs() < 1e-9, "{k}");
        // Bounced back 2 mrad below the contact: no stiffness to show.
        w.push(&sample(13, -222_000, 500_000));
        assert_eq!(w.kc_live(), None);
        // A new grasp forgets the old contact.
        w.push(&event(EventKind::GraspStarted { grasp: 2 }));
        assert_eq!(w.kc_live(), None);
    }

    /// The window keeps the last `window_s` seconds of samples on the device's time base.
    #[test]
    fn window_keeps_the_last_seconds() {
        let mut w = Watch::new(1e-3, 0.5);
        for k in 0..2000 {
            w.push(&sample(100 + k, 0, 0));
        }
        let (first, last) = (w.samples.front().unwrap().0, w.samples.back().unwrap().0);
        assert!((last - 1.999).abs() < 1e-9, "{last}");
        assert!(
            last - first <= 0.5 + 1e-9 && last - first > 0.49,
            "{first} {last}"
        );
    }

    /// Rendered into a test terminal: the state, the live K̂c, the estimate and the events
    /// appear in words, and both charts are drawn (Braille cells in their panes).
    #[test]
    fn draws_state_kc_estimate_and_charts() {
        use ratatui::backend::TestBackend;
        let mut w = Watch::new(1e-4, 2.0);
        w.push(&event(EventKind::ContactDetected {
            theta_a_urad: -220_000,
            torque_unm: 400_000,
        }));
        for k in 0..200 {
            w.push(&sample(
                k,
                -220_000 + 350 * k as i32,
                400_000 + 1500 * k as i32,
            ));
        }
        let contact = Contact {
            grasp: 1,
            estimator: proto::Estimator::TwoPoint,
            phalanx: proto::Phalanx::Distal,
            k2_um: Some(22_212),
            sigma_um: None,
            r_um: None,
            two_point_k2_um: None,
            kc_hat_unm_per_rad: 5_381_774,
            theta_a_c_urad: -221_457,
            ta_c_unm: 424_896,
            delta_ta_unm: 704_014,
            delta_theta_a_urad: 130_814,
            good: true,
        };
        w.push(&DeviceMsg::Contact(contact));
        let mut term = ratatui::Terminal::new(TestBackend::new(100, 40)).unwrap();
        term.draw(|f| draw(f, &w)).unwrap();
        let buf = term.backend().buffer();
        let text: String = (0..buf.area.height)
            .map(|y| {
                (0..buf.area.width)
                    .map(|x| buf[(x, y)].symbol().to_string())
                    .collect::<String>()
                    + "\n"
            })
            .collect();
        assert!(text.contains("state step"), "{text}");
        // Secant by hand: 1500 µN·m per 350 µrad.
        assert!(
            text.contains(&format!("K̂c live {:.3} N·m/rad", 1500.0 / 350.0)),
            "{text}"
        );
        assert!(text.contains("k2 22.21 mm"), "{text}");
        let full = Contact {
            estimator: proto::Estimator::PathFit,
            k2_um: Some(29_719),
            sigma_um: Some(1_184),
            r_um: Some(48_560),
            two_point_k2_um: Some(41_993),
            ..contact
        };
        let words = estimate_words(&full);
        assert!(
            words.contains("k2 29.72 ± 1.18 mm, R 48.56 mm")
                && words.contains("(PathFit; two-point 41.99 mm)"),
            "{words}"
        );
        assert!(text.contains("contact at θa -0.2200 rad"), "{text}");
        let braille = text
            .chars()
            .filter(|c| ('\u{2801}'..='\u{28FF}').contains(c))
            .count();
        assert!(
            braille > 50,
            "charts not drawn: {braille} Braille cells\n{text}"
        );
    }
}
