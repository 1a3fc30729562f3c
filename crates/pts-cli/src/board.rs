//! `pts board`: the host side of the crates/proto protocol, against the QEMU firmware's UART
//! socket (`--connect HOST:PORT`) or a serial device (`--connect /dev/ttyACM0`).
//!
//! Every command opens the link, sends one request and waits for its reply (or, for `grasp`,
//! for the contact or the fault that ends it) with a timeout, so a silent device gives an
//! error instead of a hang. While it waits for a grasp it polls the status, which is also the
//! device's proof that the host is still there.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use proto::{
    Command, Contact, DeviceMsg, Error, EventKind, FrameError, Param, ParamId, Reply, Request,
    StepShape, Unsupported,
};

/// How often `grasp` polls the status while it waits (the device's host-alive proof).
pub const POLL: Duration = Duration::from_millis(100);

/// The byte link: QEMU's UART socket or a serial port.
enum Link {
    Tcp(TcpStream),
    Serial(Box<dyn serialport::SerialPort>),
}

impl Link {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Link::Tcp(s) => s.read(buf),
            Link::Serial(p) => p.read(buf),
        }
    }

    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        match self {
            Link::Tcp(s) => s.write_all(bytes),
            Link::Serial(p) => p.write_all(bytes).and_then(|()| p.flush()),
        }
    }
}

/// Serial line rate (baud); a USB CDC-ACM port ignores it.
pub const SERIAL_BAUD: u32 = 115_200;

/// True when `addr` names a serial device rather than `HOST:PORT`.
pub fn is_serial(addr: &str) -> bool {
    addr.starts_with('/') || addr.to_ascii_uppercase().starts_with("COM")
}

/// A connection to the device.
pub struct Board {
    stream: Link,
    dec: proto::Decoder<DeviceMsg, { proto::MAX_FRAME }>,
    next_id: u16,
    timeout: Duration,
    /// Every unasked message seen (events, contacts, samples), in order.
    pub log: Vec<DeviceMsg>,
    /// Decoded messages not yet handled (a read can bring a reply and what followed it).
    pending: std::collections::VecDeque<Result<DeviceMsg, FrameError>>,
    /// A whole frame has been read: before it, the link may have been joined in the middle
    /// of a frame the device was sending (telemetry, a sweep's rows), and what precedes the
    /// first delimiter is dropped rather than reported.
    synced: bool,
    /// Partial frames dropped before the first whole one.
    pub joined_mid_frame: u32,
}

/// Why a command failed.
#[derive(Debug)]
pub enum BoardError {
    /// Could not connect, read or write.
    Io(String),
    /// No reply within the timeout.
    Timeout(Duration),
    /// The device refused the request.
    Device(Error),
    /// A frame from the device could not be read.
    Frame(FrameError),
    /// A recording is incomplete.
    Record(RecordError),
    /// The calibration sweep did not finish, or its record is incomplete.
    Sweep(SweepError),
}

impl std::fmt::Display for BoardError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BoardError::Io(e) => write!(f, "link: {e}"),
            BoardError::Timeout(t) => write!(f, "no reply within {:.1} s", t.as_secs_f64()),
            BoardError::Device(e) => write!(f, "{}", describe(e)),
            BoardError::Frame(e) => write!(f, "bad frame from the device: {e:?}"),
            BoardError::Record(e) => write!(f, "recording: {e}"),
            BoardError::Sweep(e) => write!(f, "calibration sweep: {e}"),
        }
    }
}

/// What to try when nothing answers at a TCP address: the QEMU device is not running, or
/// the board is on a serial port.
fn tcp_hint(e: &std::io::Error) -> &'static str {
    match e.kind() {
        std::io::ErrorKind::ConnectionRefused | std::io::ErrorKind::TimedOut => {
            " (no device listens there: start the simulated one with `cargo xtask device`, \
             or give the board's serial port, `--connect /dev/ttyACM0`)"
        }
        _ => "",
    }
}

/// What to try when the board's serial port cannot be opened.
fn serial_hint(e: &serialport::Error) -> &'static str {
    match e.kind() {
        serialport::ErrorKind::NoDevice
        | serialport::ErrorKind::Io(std::io::ErrorKind::NotFound) => {
            " (no such port: is the board plugged in and flashed? `ls /dev/ttyACM*` lists the ports)"
        }
        serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => {
            " (not allowed to open it: add your user to the `dialout` group and log in again)"
        }
        _ => "",
    }
}

/// A device error in words (the parameter, the value and the allowed range for a bad value).
pub fn describe(e: &Error) -> String {
    match e {
        Error::BadValue {
            param,
            value,
            range,
        } => format!(
            "{} = {value} is outside the allowed range {}..={}",
            param.name(),
            range.min,
            range.max
        ),
        Error::UnknownCommand { tag } => {
            format!("the device does not know command tag {tag}")
        }
        Error::UnknownChoice { param } => format!("{}: no such choice on this build", param.name()),
        Error::Busy { state } => format!("busy: the device is in state {}", state.name()),
        Error::FaultLatched { fault } => format!(
            "fault latched ({:?}, value {}): send `stop` to acknowledge",
            fault.kind, fault.value
        ),
        Error::BadFrame(f) => format!("the device could not read the request: {f:?}"),
        Error::VersionMismatch { host, device } => {
            format!("protocol version mismatch: host {host}, device {device}")
        }
        Error::ConfigRejected => "the controller refused the configuration".into(),
        Error::NotSupported { what } => match what {
            Unsupported::Estimator(e) => format!("estimator {e:?} is not in this firmware build"),
            other => format!("not supported by this firmware: {other:?}"),
        },
        Error::Store { why } => {
            format!(
                "settings store: {} (the settings in use are unchanged)",
                store_failure_text(*why)
            )
        }
    }
}

/// Why the settings store could not give or keep settings, in words.
pub fn store_failure_text(why: proto::StoreFailure) -> &'static str {
    use proto::StoreFailure as F;
    match why {
        F::Empty => "the store holds no settings yet",
        F::Corrupt => "no record in the store is intact",
        F::Foreign => "the store's record is of another settings layout",
        F::Invalid => "the stored settings are out of range or not for this build",
        F::Flash => "the flash refused the operation",
    }
}

impl Board {
    /// Connects to `addr`: `HOST:PORT` (QEMU's socket) or a serial device path.
    pub fn connect(addr: &str, timeout: Duration) -> Result<Board, BoardError> {
        let short = Duration::from_millis(20);
        let stream = if is_serial(addr) {
            let port = serialport::new(addr, SERIAL_BAUD)
                .timeout(short)
                .open()
                .map_err(|e| BoardError::Io(format!("{addr}: {e}{}", serial_hint(&e))))?;
            Link::Serial(port)
        } else {
            let sock = addr.parse().map_err(|e| {
                BoardError::Io(format!(
                    "{addr}: {e} (expected HOST:PORT or a serial device path)"
                ))
            })?;
            let stream = TcpStream::connect_timeout(&sock, timeout)
                .map_err(|e| BoardError::Io(format!("{addr}: {e}{}", tcp_hint(&e))))?;
            stream
                .set_read_timeout(Some(short))
                .map_err(|e| BoardError::Io(e.to_string()))?;
            let _ = stream.set_nodelay(true);
            Link::Tcp(stream)
        };
        let mut b = Board {
            stream,
            dec: proto::Decoder::new(),
            next_id: 1,
            timeout,
            log: Vec::new(),
            pending: Default::default(),
            synced: false,
            joined_mid_frame: 0,
        };
        // A delimiter first: the device drops whatever partial frame it held.
        b.write(&[0])?;
        Ok(b)
    }

    /// Sends raw bytes.
    pub fn write(&mut self, bytes: &[u8]) -> Result<(), BoardError> {
        self.stream
            .write_all(bytes)
            .map_err(|e| BoardError::Io(e.to_string()))
    }

    /// Reads what is there (up to the socket's short timeout): decoded messages, after any
    /// not yet handled.
    pub fn poll(&mut self) -> Result<Vec<Result<DeviceMsg, FrameError>>, BoardError> {
        self.fill()?;
        Ok(self.pending.drain(..).collect())
    }

    /// One read of the link into the pending messages.
    fn fill(&mut self) -> Result<(), BoardError> {
        let mut buf = [0u8; 4096];
        match self.stream.read(&mut buf) {
            Ok(0) => return Err(BoardError::Io("the device closed the link".into())),
            Ok(n) => {
                let (pending, synced, dropped) = (
                    &mut self.pending,
                    &mut self.synced,
                    &mut self.joined_mid_frame,
                );
                self.dec.feed(&buf[..n], |r| match r {
                    Err(_) if !*synced => *dropped += 1,
                    r => {
                        *synced = true;
                        pending.push_back(r)
                    }
                });
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(BoardError::Io(e.to_string())),
        }
        Ok(())
    }

    /// The next message, reading the link when none is pending; `None` when nothing arrived
    /// within the socket's short timeout. Messages after the one returned stay pending, so
    /// a caller that stops at a reply loses nothing that came with it.
    fn next(&mut self) -> Result<Option<Result<DeviceMsg, FrameError>>, BoardError> {
        if self.pending.is_empty() {
            self.fill()?;
        }
        Ok(self.pending.pop_front())
    }

    /// Sends a request; returns its id.
    pub fn send(&mut self, cmd: Command) -> Result<u16, BoardError> {
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1).max(1);
        let mut buf = [0u8; proto::MAX_FRAME];
        let n = proto::encode(&Request { id, cmd }, &mut buf)
            .map_err(|e| BoardError::Io(format!("encode: {e:?}")))?;
        self.write(&buf[..n])?;
        Ok(id)
    }

    /// Waits for the reply to `id` (or a frame error answered with id 0).
    pub fn wait_reply(&mut self, id: u16) -> Result<Reply, BoardError> {
        let t0 = Instant::now();
        while t0.elapsed() < self.timeout {
            match self.next()? {
                Some(Ok(DeviceMsg::Reply { id: rid, result })) if rid == id || rid == 0 => {
                    return result.map_err(BoardError::Device);
                }
                Some(Ok(other)) => self.log.push(other),
                Some(Err(e)) => return Err(BoardError::Frame(e)),
                None => {}
            }
        }
        Err(BoardError::Timeout(self.timeout))
    }

    /// One request and its reply.
    pub fn request(&mut self, cmd: Command) -> Result<Reply, BoardError> {
        let id = self.send(cmd)?;
        self.wait_reply(id)
    }

    /// Records one grasp at the control rate ([`Recording`]): telemetry set to one sample per
    /// tick for the grasp, then back to the rate it had. Fails with [`RecordError`] (as a
    /// [`BoardError::Record`]) when a tick has no sample.
    pub fn record(&mut self, give_up: Duration) -> Result<Recording, BoardError> {
        let Reply::Drive(drive) = self.request(Command::Drive)? else {
            return Err(BoardError::Io(
                "the device answered `drive` with another reply".into(),
            ));
        };
        let Reply::Status(status) = self.request(Command::Status)? else {
            return Err(BoardError::Io(
                "the device answered `status` with another reply".into(),
            ));
        };
        let control_hz = (1.0 / drive.dt_s).round();
        let max_hz = ParamId::TelemetryRate.range().map_or(0.0, |r| r.max);
        if !(control_hz > 0.0 && control_hz <= max_hz) {
            return Err(BoardError::Record(RecordError::RateTooHigh {
                control_hz,
                max_hz,
            }));
        }
        let before = status.settings.telemetry_hz;
        self.request(Command::Set(Param::TelemetryHz(control_hz as u16)))?;
        self.log.clear();
        let outcome = self.grasp(give_up);
        // Back to the previous rate whatever happened (best effort: the grasp's error wins).
        let restored = self.request(Command::Set(Param::TelemetryHz(before)));
        let outcome = outcome?;
        restored?;
        // The sample of the tick that ended the grasp may still be on its way.
        let t0 = Instant::now();
        let samples = loop {
            match grasp_samples(&self.log) {
                Err(RecordError::NoEnd) if t0.elapsed() < self.timeout => {
                    if let Some(Ok(m)) = self.next()? {
                        self.log.push(m);
                    }
                }
                r => break r.map_err(BoardError::Record)?,
            }
        };
        Ok(Recording {
            outcome,
            drive,
            settings: status.settings,
            samples,
        })
    }

    /// Lets go: the device ramps the torque down and opens the finger back to rest (from
    /// holding; in any other state it switches the torque off). Polls the status until the
    /// device is idle, stopped or in a fault, and returns that state; `give_up` bounds the
    /// wait.
    pub fn release(&mut self, give_up: Duration) -> Result<Released, BoardError> {
        use proto::DeviceState as D;
        self.log.clear();
        self.request(Command::Release)?;
        let t0 = Instant::now();
        while t0.elapsed() < give_up {
            let Reply::Status(st) = self.request(Command::Status)? else {
                return Err(BoardError::Io(
                    "the device answered `status` with another reply".into(),
                ));
            };
            if matches!(st.state, D::Idle | D::Stopped | D::Fault(_)) {
                let theta_a_urad = self.log.iter().rev().find_map(|m| match m {
                    DeviceMsg::Sample(x) => Some(x.theta_a_urad),
                    _ => None,
                });
                return Ok(Released {
                    state: st.state,
                    theta_a_urad,
                });
            }
            std::thread::sleep(POLL);
        }
        Err(BoardError::Timeout(give_up))
    }

    /// Runs the device's calibration sweep (the finger must be free) and collects its rows
    /// until it ends. Polls the status meanwhile; `give_up` bounds the wait. Fails with
    /// [`SweepError`] (as a [`BoardError::Sweep`]) when it ended early or rows are missing.
    /// `progress` sees each row as it arrives, with the count so far.
    pub fn sweep(
        &mut self,
        give_up: Duration,
        progress: &mut dyn FnMut(&proto::Sample, usize),
    ) -> Result<SweepRecording, BoardError> {
        let Reply::Drive(drive) = self.request(Command::Drive)? else {
            return Err(BoardError::Io(
                "the device answered `drive` with another reply".into(),
            ));
        };
        self.log.clear();
        self.request(Command::Calibrate)?;
        let t0 = Instant::now();
        let mut poll = StatusPoll::new();
        let mut samples = vec![];
        let mut fault = None;
        while t0.elapsed() < give_up {
            let Some(m) = self.next_polling(&mut poll)? else {
                continue;
            };
            match m {
                DeviceMsg::Sample(x) if x.state == proto::DeviceState::Sweeping => {
                    samples.push(x);
                    progress(&x, samples.len());
                }
                DeviceMsg::Event(ev) => {
                    self.log.push(DeviceMsg::Event(ev));
                    match ev.kind {
                        EventKind::Fault(f) => fault = Some(f),
                        EventKind::SweepEnded { end, rows } => {
                            // The device sends every row before the end.
                            if end != proto::SweepEnd::Done {
                                // A fault's event follows the loop's trip: wait for it briefly.
                                if end == proto::SweepEnd::Fault && fault.is_none() {
                                    fault = self.fault_within(Duration::from_millis(500))?;
                                }
                                return Err(BoardError::Sweep(SweepError::Ended { end, fault }));
                            }
                            return check_sweep(drive, samples, rows);
                        }
                        _ => {}
                    }
                }
                other => self.log.push(other),
            }
        }
        // Do not leave the finger sweeping unattended.
        let _ = self.request(Command::Stop);
        Err(BoardError::Timeout(give_up))
    }

    /// The next fault event within `wait`, if any.
    fn fault_within(&mut self, wait: Duration) -> Result<Option<proto::Fault>, BoardError> {
        let t0 = Instant::now();
        while t0.elapsed() < wait {
            if let Some(Ok(DeviceMsg::Event(proto::Event {
                kind: EventKind::Fault(f),
                ..
            }))) = self.next()?
            {
                return Ok(Some(f));
            }
        }
        Ok(None)
    }

    /// Starts a grasp and waits for its end: the contact estimate, a fault or a stop. Polls
    /// the status meanwhile; `give_up` bounds the wait.
    pub fn grasp(&mut self, give_up: Duration) -> Result<Outcome, BoardError> {
        self.request(Command::Grasp)?;
        let t0 = Instant::now();
        let mut poll = StatusPoll::new();
        let mut contact = None;
        while t0.elapsed() < give_up {
            if let Some(m) = self.next_polling(&mut poll)? {
                match m {
                    DeviceMsg::Contact(c) => {
                        contact = Some(c);
                        self.log.push(DeviceMsg::Contact(c));
                    }
                    DeviceMsg::Event(ev) => {
                        self.log.push(DeviceMsg::Event(ev));
                        match ev.kind {
                            EventKind::Holding | EventKind::Releasing => {
                                if let Some(c) = contact {
                                    return Ok(Outcome::Contact(c));
                                }
                            }
                            EventKind::Fault(f) => return Ok(Outcome::Fault(f)),
                            EventKind::Stopped { .. } => return Ok(Outcome::Stopped),
                            _ => {}
                        }
                    }
                    other => self.log.push(other),
                }
            }
        }
        Err(BoardError::Timeout(give_up))
    }

    /// The next unasked message while a command runs on the device, with the status polled
    /// every [`POLL`] meanwhile (the device's proof that the host is there): the polls'
    /// replies are consumed, a refused one is an error, as is a bad frame. `None` when
    /// nothing arrived within the link's short timeout.
    fn next_polling(&mut self, poll: &mut StatusPoll) -> Result<Option<DeviceMsg>, BoardError> {
        if poll.last.elapsed() >= POLL && poll.pending.is_none() {
            poll.pending = Some(self.send(Command::Status)?);
            poll.last = Instant::now();
        }
        match self.next()? {
            None => Ok(None),
            Some(Err(e)) => Err(BoardError::Frame(e)),
            Some(Ok(DeviceMsg::Reply { id, result })) => {
                if Some(id) == poll.pending {
                    poll.pending = None;
                }
                result.map(|_| None).map_err(BoardError::Device)
            }
            Some(Ok(m)) => Ok(Some(m)),
        }
    }
}

/// The status polls of a command that runs on the device ([`Board::next_polling`]).
struct StatusPoll {
    last: Instant,
    /// The poll whose reply has not come yet.
    pending: Option<u16>,
}

impl StatusPoll {
    fn new() -> Self {
        Self {
            last: Instant::now(),
            pending: None,
        }
    }
}

/// Where a release left the finger.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Released {
    /// The device's state (idle, or stopped or a fault when it could not open).
    pub state: proto::DeviceState,
    /// θa of the last telemetry sample (µrad), when the telemetry is on.
    pub theta_a_urad: Option<i32>,
}

/// Why a calibration sweep gives no record to identify from.
#[derive(Clone, Debug, PartialEq)]
pub enum SweepError {
    /// The sweep ended early (bridge off); `fault` is the fault the device reported with it.
    Ended {
        /// How it ended.
        end: proto::SweepEnd,
        /// The fault, when one tripped it.
        fault: Option<proto::Fault>,
    },
    /// Rows are missing (the telemetry queue or the link could not keep up).
    Lost {
        /// Rows received.
        got: usize,
        /// Rows the device recorded.
        of: u32,
    },
}

impl std::fmt::Display for SweepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SweepError::Ended { end, fault: None } => write!(
                f,
                "it ended early ({}): the bridge is off, nothing to identify from",
                end.name()
            ),
            SweepError::Ended {
                end,
                fault: Some(x),
            } => write!(
                f,
                "it ended early ({}, fault {:?} value {}): the bridge is off; send `stop` to \
                 acknowledge",
                end.name(),
                x.kind,
                x.value
            ),
            SweepError::Lost { got, of } => write!(
                f,
                "{got} of the {of} rows the device recorded arrived (the link could not keep \
                 up): not identified from a gapped record"
            ),
        }
    }
}

/// One calibration sweep as the device recorded it.
#[derive(Clone, Debug)]
pub struct SweepRecording {
    /// The device's drive constants and control period.
    pub drive: proto::Drive,
    /// Its rows, in tick order, evenly spaced.
    pub samples: Vec<proto::Sample>,
}

impl SweepRecording {
    /// The rows as trace rows ([`crate::sweep::firmware_row`] with the nominal file), time
    /// from the first row.
    pub fn rows(&self, nominal: &pts::config::FingerFile) -> Vec<crate::trace::TraceRow> {
        let t0 = self.samples.first().map_or(0, |x| x.tick);
        self.samples
            .iter()
            .map(|x| {
                let t = f64::from(x.tick.wrapping_sub(t0)) * self.drive.dt_s;
                crate::sweep::firmware_row(nominal, t, x)
            })
            .collect()
    }
}

/// One grasp recorded at the control rate: every tick's sample from the grasp's first tick to
/// the event that ended it, with the drive constants and settings the controller ran with.
#[derive(Clone, Debug)]
pub struct Recording {
    /// How the grasp ended.
    pub outcome: Outcome,
    /// The device's drive constants and control period.
    pub drive: proto::Drive,
    /// The settings of the grasp.
    pub settings: proto::Settings,
    /// One sample per control tick, consecutive ticks.
    pub samples: Vec<proto::Sample>,
}

/// Why a recording is incomplete.
#[derive(Clone, Debug, PartialEq)]
pub enum RecordError {
    /// The control rate is above what the telemetry can carry (Hz).
    RateTooHigh {
        /// The control rate 1/dt (Hz).
        control_hz: f64,
        /// The largest telemetry rate (Hz).
        max_hz: f64,
    },
    /// No `GraspStarted` event was seen.
    NoStart,
    /// No sample in a state that ends the grasp (holding, a fault, stopped) was seen.
    NoEnd,
    /// Samples are missing (the telemetry queue or the link could not keep up).
    Lost {
        /// Ticks without a sample.
        missing: u64,
        /// Ticks the grasp lasted.
        of: u64,
        /// The first missing tick.
        first: u32,
    },
}

impl std::fmt::Display for RecordError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RecordError::RateTooHigh { control_hz, max_hz } => write!(
                f,
                "the control rate {control_hz} Hz is above the largest telemetry rate {max_hz} Hz: \
                 the grasp cannot be recorded at every tick"
            ),
            RecordError::NoStart => write!(f, "the device did not report the grasp's start"),
            RecordError::NoEnd => write!(f, "no sample shows the grasp's end"),
            RecordError::Lost { missing, of, first } => write!(
                f,
                "{missing} of {of} control ticks have no sample (first missing tick {first}): the \
                 telemetry could not keep up; the recording would not replay exactly"
            ),
        }
    }
}

/// A finished sweep's rows, checked complete: as many as the device recorded, evenly spaced.
pub fn check_sweep(
    drive: proto::Drive,
    mut samples: Vec<proto::Sample>,
    rows: u32,
) -> Result<SweepRecording, BoardError> {
    samples.sort_by_key(|x| x.tick);
    samples.dedup_by_key(|x| x.tick);
    let spaced = samples
        .windows(3)
        .all(|w| w[1].tick - w[0].tick == w[2].tick - w[1].tick);
    if samples.len() != rows as usize || !spaced || samples.len() < 2 {
        return Err(BoardError::Sweep(SweepError::Lost {
            got: samples.len(),
            of: rows,
        }));
    }
    Ok(SweepRecording { drive, samples })
}

/// True for the states a grasp ends in: its last recorded tick is the first in one of them.
fn ends_grasp(s: proto::DeviceState) -> bool {
    use proto::DeviceState as D;
    matches!(
        s,
        D::Holding | D::Releasing | D::Opening | D::Idle | D::Stopped | D::Fault(_)
    )
}

/// The samples of one grasp out of a message log: those after the last `GraspStarted` event
/// (whose tick is the device's last tick before the grasp) up to the first in a state that
/// ends the grasp, checked to cover every tick.
pub fn grasp_samples(log: &[DeviceMsg]) -> Result<Vec<proto::Sample>, RecordError> {
    let start = log
        .iter()
        .rev()
        .find_map(|m| match m {
            DeviceMsg::Event(proto::Event {
                tick,
                kind: EventKind::GraspStarted { .. },
            }) => Some(*tick),
            _ => None,
        })
        .ok_or(RecordError::NoStart)?;
    let mut v: Vec<proto::Sample> = log
        .iter()
        .filter_map(|m| match m {
            DeviceMsg::Sample(s) if s.tick > start => Some(*s),
            _ => None,
        })
        .collect();
    v.sort_by_key(|s| s.tick);
    v.dedup_by_key(|s| s.tick);
    let end = v
        .iter()
        .position(|s| ends_grasp(s.state))
        .ok_or(RecordError::NoEnd)?;
    v.truncate(end + 1);
    let of = u64::from(v[end].tick - start);
    let missing = of - v.len() as u64;
    if missing > 0 {
        let first = v
            .iter()
            .zip(start + 1..)
            .find(|(s, t)| s.tick != *t)
            .map_or(start + 1, |(_, t)| t);
        return Err(RecordError::Lost { missing, of, first });
    }
    Ok(v)
}

impl Recording {
    /// The recording as a trace CSV that `pts estimate --trace` replays through the
    /// controller: the `# pts-sim` line with the drive constants and settings, then one row
    /// per tick with the raw encoder count and ADC code.
    pub fn write_csv(&self, out: &mut impl Write) -> std::io::Result<()> {
        use crate::replay::{MetaController, MetaDrive, TraceMeta};
        let d = &self.drive;
        let s = &self.settings;
        let meta = TraceMeta {
            dta_nm: s.delta_ta_nm,
            dt_s: d.dt_s,
            drive: Some(MetaDrive {
                gear_ratio: d.gear_ratio,
                efficiency: d.efficiency,
                kt_nm_per_a: d.kt_nm_per_a,
                resistance_ohm: d.resistance_ohm,
                bus_v: d.bus_v,
                counts_per_rev: d.counts_per_rev,
                amps_per_code: d.amps_per_code,
                zero_code: d.zero_code,
                // The device does not report them: the finger file's stay.
                inertia_kgm2: None,
                backlash_rad: None,
            }),
            controller: MetaController {
                estimator: Some(match s.estimator {
                    proto::Estimator::TwoPoint => crate::method::Method::TwoPoint,
                    proto::Estimator::PathFit => crate::method::Method::Pathfit,
                }),
                step_ramp_nm_per_s: Some(match s.step_shape {
                    StepShape::Step => 0.0,
                    StepShape::RampNmPerS(r) => r,
                }),
                approach_speed_rad_s: Some(s.approach_speed_rad_s),
                approach_max_nm: Some(s.approach_max_nm),
                seating: Some(s.seating),
            },
        };
        writeln!(out, "{} source=pts-board-record", meta.line())?;
        let t0 = self.samples.first().map_or(0, |x| x.tick);
        let rows: Vec<crate::trace::TraceRow> = self
            .samples
            .iter()
            .map(|x| crate::trace::TraceRow {
                t_s: f64::from(x.tick.wrapping_sub(t0)) * d.dt_s,
                theta_a_rad: f64::from(x.theta_a_urad) * 1e-6,
                torque_nm: f64::from(x.torque_unm) * 1e-6,
                torque_ref_nm: Some(f64::from(x.torque_ref_unm) * 1e-6),
                duty: Some(f64::from(x.duty) / f64::from(grasp::DUTY_MAX)),
                state: Some(x.state.name().to_string()),
                encoder_count: Some(x.encoder_count),
                current_code: Some(x.current_code),
                ..Default::default()
            })
            .collect();
        crate::trace::write_csv(&rows, out)
    }
}

/// How a grasp ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// An estimate.
    Contact(Contact),
    /// A fault (bridge off).
    Fault(proto::Fault),
    /// Stopped by a stop command.
    Stopped,
}

/// A parameter from its command-line name and value text.
pub fn parse_param(name: &str, value: &str) -> Result<Param, String> {
    let id = ParamId::from_name(name).ok_or_else(|| {
        let names: Vec<&str> = ParamId::ALL.iter().map(|p| p.name()).collect();
        format!("no parameter {name}; parameters: {}", names.join(", "))
    })?;
    let num = || -> Result<f64, String> {
        value
            .parse::<f64>()
            .map_err(|_| format!("{name} = {value}: not a number"))
    };
    Ok(match id {
        ParamId::DeltaTa => Param::DeltaTaNm(num()?),
        ParamId::ApproachSpeed => Param::ApproachSpeedRadS(num()?),
        ParamId::ApproachTorqueMax => Param::ApproachMaxNm(num()?),
        ParamId::StepShape => match value {
            "step" => Param::StepShape(StepShape::Step),
            _ => Param::StepShape(StepShape::RampNmPerS(num()?)),
        },
        ParamId::TelemetryRate => {
            let v = num()?;
            if !(0.0..=f64::from(u16::MAX)).contains(&v) || v.fract() != 0.0 {
                return Err(format!(
                    "{name} = {value}: a whole number of Hz in 0..=10000 expected"
                ));
            }
            Param::TelemetryHz(v as u16)
        }
        ParamId::Estimator => Param::Estimator(match value {
            "two-point" => proto::Estimator::TwoPoint,
            "path-fit" => proto::Estimator::PathFit,
            _ => return Err(format!("{name} = {value}: allowed two-point, path-fit")),
        }),
        ParamId::Seating => Param::Seating(match value {
            "on" => true,
            "off" => false,
            _ => return Err(format!("{name} = {value}: allowed on, off")),
        }),
        ParamId::Scene => Param::Scene(
            proto::SceneName::try_from(value)
                .map_err(|_| format!("{name} = {value}: at most 24 bytes"))?,
        ),
    })
}

/// A parameter as `pts board set` takes it: its name and the text of its value (what
/// [`parse_param`] reads back to the same parameter).
pub fn param_text(p: &Param) -> (&'static str, String) {
    let value = match p {
        Param::DeltaTaNm(v) | Param::ApproachSpeedRadS(v) | Param::ApproachMaxNm(v) => {
            v.to_string()
        }
        Param::StepShape(StepShape::Step) => "step".to_string(),
        Param::StepShape(StepShape::RampNmPerS(r)) => r.to_string(),
        Param::TelemetryHz(h) => h.to_string(),
        Param::Estimator(proto::Estimator::TwoPoint) => "two-point".to_string(),
        Param::Estimator(proto::Estimator::PathFit) => "path-fit".to_string(),
        Param::Scene(name) => name.to_string(),
        Param::Seating(true) => "on".to_string(),
        Param::Seating(false) => "off".to_string(),
    };
    (p.id().name(), value)
}

/// Every setting as `name value`, comma-separated, in the words `pts board set` takes.
pub fn settings_text(s: &proto::Settings) -> String {
    ParamId::ALL
        .iter()
        .filter_map(|id| s.get(*id))
        .map(|p| {
            let (name, value) = param_text(&p);
            format!("{name} {value}")
        })
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Nothing at the address, or no such port: the message says what to try.
    #[test]
    fn a_link_that_cannot_open_says_what_to_try() {
        let free = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = free.local_addr().unwrap().to_string();
        drop(free);
        let e = Board::connect(&addr, Duration::from_millis(500))
            .err()
            .unwrap();
        assert!(e.to_string().contains("cargo xtask device"), "{e}");
        let e = Board::connect("/dev/pts-no-such-port", Duration::from_millis(500))
            .err()
            .unwrap();
        assert!(e.to_string().contains("plugged in"), "{e}");
    }

    /// What `get` and `status` print is what `set` takes: every parameter's text parses back
    /// to the same parameter.
    #[test]
    fn a_parameter_read_back_sets_the_same_value() {
        let params = [
            Param::DeltaTaNm(0.8),
            Param::DeltaTaNm(0.123_456_789),
            Param::StepShape(StepShape::Step),
            Param::StepShape(StepShape::RampNmPerS(4.0)),
            Param::StepShape(StepShape::RampNmPerS(0.0)),
            Param::Estimator(proto::Estimator::TwoPoint),
            Param::Estimator(proto::Estimator::PathFit),
            Param::ApproachSpeedRadS(0.25),
            Param::ApproachMaxNm(1.5),
            Param::TelemetryHz(10_000),
            Param::Scene(proto::SceneName::try_from("cyl10_k2_20").unwrap()),
            Param::Seating(true),
            Param::Seating(false),
        ];
        for id in ParamId::ALL {
            assert!(params.iter().any(|p| p.id() == id), "{id:?} untested");
        }
        for p in params {
            let (name, value) = param_text(&p);
            assert_eq!(parse_param(name, &value), Ok(p.clone()), "{name} {value}");
        }
        let s = proto::Settings {
            layout: proto::Settings::LAYOUT,
            delta_ta_nm: 0.6,
            step_shape: StepShape::Step,
            estimator: proto::Estimator::PathFit,
            approach_speed_rad_s: 0.25,
            approach_max_nm: 1.5,
            telemetry_hz: 50,
            seating: false,
        };
        assert_eq!(
            settings_text(&s),
            "delta_ta_nm 0.6, step_ramp_nm_per_s step, estimator path-fit, \
             approach_speed_rad_s 0.25, approach_max_nm 1.5, telemetry_hz 50, seating off"
        );
    }

    /// A host that connects while the device streams (a sweep's rows) reads the tail of a
    /// frame first: dropped, the reply after it read; corruption after that is reported.
    #[test]
    fn a_link_joined_mid_frame_drops_the_partial_frame_only() {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap().to_string();
        let server = std::thread::spawn(move || {
            let (mut c, _) = l.accept().unwrap();
            let frame = |id| {
                let mut buf = [0u8; proto::MAX_FRAME];
                let n = DeviceMsg::Reply {
                    id,
                    result: Ok(Reply::Ack),
                }
                .encode(&mut buf)
                .unwrap();
                buf[..n].to_vec()
            };
            let (one, mut two) = (frame(1), frame(2));
            c.write_all(&one[3..]).unwrap();
            c.write_all(&one).unwrap();
            two[2] ^= 0x40;
            c.write_all(&two).unwrap();
            std::thread::sleep(Duration::from_millis(500));
        });
        let mut b = Board::connect(&addr, Duration::from_secs(2)).unwrap();
        assert!(matches!(b.wait_reply(1), Ok(Reply::Ack)));
        assert_eq!(b.joined_mid_frame, 1);
        assert!(matches!(b.wait_reply(2), Err(BoardError::Frame(_))));
        server.join().unwrap();
    }

    /// A missing serial device or an unreachable socket is an error naming it, not a hang.
    #[test]
    fn unreachable_links_are_named_errors() {
        let e = Board::connect("/dev/no_such_tty_for_pts", Duration::from_millis(200))
            .err()
            .expect("no such device");
        assert!(e.to_string().contains("/dev/no_such_tty_for_pts"), "{e}");
        let e = Board::connect("not an address", Duration::from_millis(200))
            .err()
            .expect("not an address");
        assert!(e.to_string().contains("HOST:PORT"), "{e}");
        // A closed local port: refused at once.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .unwrap();
        let t = std::time::Instant::now();
        assert!(Board::connect(&format!("127.0.0.1:{port}"), Duration::from_secs(2)).is_err());
        assert!(t.elapsed() < Duration::from_secs(3));
    }

    #[test]
    fn parameters_parse_by_name_and_errors_name_the_range() {
        assert_eq!(
            parse_param("delta_ta_nm", "0.4").unwrap(),
            Param::DeltaTaNm(0.4)
        );
        assert_eq!(
            parse_param("estimator", "path-fit").unwrap(),
            Param::Estimator(proto::Estimator::PathFit)
        );
        assert_eq!(
            parse_param("seating", "off").unwrap(),
            Param::Seating(false)
        );
        assert_eq!(parse_param("seating", "on").unwrap(), Param::Seating(true));
        let e = parse_param("seating", "maybe").unwrap_err();
        assert!(e.contains("maybe") && e.contains("on, off"), "{e}");
        assert!(parse_param("delta_ta", "0.4").is_err());
        assert!(parse_param("delta_ta_nm", "x").is_err());
        assert!(is_serial("/dev/ttyACM0") && is_serial("COM3") && !is_serial("127.0.0.1:4321"));
        let e = Param::DeltaTaNm(9.0).check().unwrap_err();
        assert_eq!(
            describe(&e),
            "delta_ta_nm = 9 is outside the allowed range 0.05..=1.5"
        );
    }

    fn sample(tick: u32) -> DeviceMsg {
        DeviceMsg::Sample(proto::Sample {
            tick,
            theta_a_urad: -850_000 + tick as i32,
            torque_unm: 1000,
            torque_ref_unm: 1200,
            duty: -50,
            state: proto::DeviceState::Approach,
            encoder_count: tick as u16,
            current_code: 2040,
        })
    }

    fn started(tick: u32) -> DeviceMsg {
        DeviceMsg::Event(proto::Event {
            tick,
            kind: EventKind::GraspStarted { grasp: 1 },
        })
    }

    /// The grasp's samples are those after its start event up to its end; a tick without a
    /// sample is an error naming how many and the first, never a silently shorter trace.
    #[test]
    fn grasp_samples_cover_every_tick_or_say_what_is_missing() {
        let mut log: Vec<DeviceMsg> = (90..=100).map(sample).collect();
        log.push(started(100));
        log.extend((101..=120).map(sample));
        // Ticks 110… are the holding state: the grasp ends at 110.
        for m in &mut log {
            if let DeviceMsg::Sample(s) = m {
                if s.tick >= 110 {
                    s.state = proto::DeviceState::Holding;
                }
            }
        }
        let v = grasp_samples(&log).unwrap();
        assert_eq!(v.len(), 10);
        assert_eq!(v.first().map(|s| s.tick), Some(101));
        assert_eq!(v.last().map(|s| s.tick), Some(110));
        let mut gaps = log.clone();
        gaps.retain(|m| !matches!(m, DeviceMsg::Sample(s) if s.tick == 105 || s.tick == 107));
        assert_eq!(
            grasp_samples(&gaps),
            Err(RecordError::Lost {
                missing: 2,
                of: 10,
                first: 105
            })
        );
        let no_start: Vec<DeviceMsg> = (1..20).map(sample).collect();
        assert_eq!(grasp_samples(&no_start), Err(RecordError::NoStart));
        // Started, but never ended (or the end's samples never came): an error, not a short trace.
        let mut no_end: Vec<DeviceMsg> = vec![started(100)];
        no_end.extend((101..=105).map(sample));
        assert_eq!(grasp_samples(&no_end), Err(RecordError::NoEnd));
    }

    /// A recording's CSV reads back as a trace with the raw columns, the control period and
    /// the settings it was taken with (what makes the replay exact).
    #[test]
    fn recording_csv_carries_what_the_replay_needs() {
        let settings = proto::Settings {
            delta_ta_nm: 0.6,
            step_shape: StepShape::RampNmPerS(2.5),
            estimator: proto::Estimator::PathFit,
            approach_speed_rad_s: 0.3,
            approach_max_nm: 1.2,
            layout: proto::Settings::LAYOUT,
            telemetry_hz: 50,
            seating: false,
        };
        let rec = Recording {
            outcome: Outcome::Stopped,
            drive: proto::Drive {
                dt_s: 1e-4,
                gear_ratio: 256.0,
                efficiency: 0.7,
                kt_nm_per_a: 8.23e-3,
                resistance_ohm: 8.0,
                bus_v: 5.0,
                counts_per_rev: 64.0,
                amps_per_code: 1.0 / 4096.0,
                zero_code: 2048.0,
                theta_a_rest_rad: -0.85,
            },
            settings,
            samples: (101..=110)
                .map(|t| match sample(t) {
                    DeviceMsg::Sample(s) => s,
                    _ => unreachable!(),
                })
                .collect(),
        };
        let mut out = Vec::new();
        rec.write_csv(&mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        let meta = crate::replay::TraceMeta::find(&text).expect("meta line");
        assert_eq!(meta.dta_nm, 0.6);
        assert_eq!(meta.dt_s, 1e-4);
        let d = meta.drive.expect("drive constants");
        assert_eq!(
            (d.gear_ratio, d.amps_per_code, d.zero_code),
            (256.0, 1.0 / 4096.0, 2048.0)
        );
        let c = meta.controller;
        assert_eq!(c.estimator, Some(crate::method::Method::Pathfit));
        assert_eq!(c.step_ramp_nm_per_s, Some(2.5));
        assert_eq!(c.approach_speed_rad_s, Some(0.3));
        assert_eq!(c.approach_max_nm, Some(1.2));
        assert_eq!(c.seating, Some(false));
        let tr = crate::trace::read_csv(&text, &|i| i).unwrap();
        assert_eq!(tr.len(), 10);
        assert_eq!(tr.encoder_count(3), Some(104));
        assert_eq!(tr.current_code(3), Some(2040));
        assert!((tr.t_s[3] - 3e-4).abs() < 1e-12);
        assert!((tr.theta_a_rad[3] - (-0.849_896)).abs() < 1e-12);
    }
}
