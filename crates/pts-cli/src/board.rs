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
}

impl std::fmt::Display for BoardError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BoardError::Io(e) => write!(f, "link: {e}"),
            BoardError::Timeout(t) => write!(f, "no reply within {:.1} s", t.as_secs_f64()),
            BoardError::Device(e) => write!(f, "{}", describe(e)),
            BoardError::Frame(e) => write!(f, "bad frame from the device: {e:?}"),
        }
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
            format!("settings store: {why:?} (the settings in use are unchanged)")
        }
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
                .map_err(|e| BoardError::Io(format!("{addr}: {e}")))?;
            Link::Serial(port)
        } else {
            let sock = addr.parse().map_err(|e| {
                BoardError::Io(format!(
                    "{addr}: {e} (expected HOST:PORT or a serial device path)"
                ))
            })?;
            let stream = TcpStream::connect_timeout(&sock, timeout)
                .map_err(|e| BoardError::Io(format!("{addr}: {e}")))?;
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

    /// Reads what is there (up to the socket's short timeout): decoded messages.
    pub fn poll(&mut self) -> Result<Vec<Result<DeviceMsg, FrameError>>, BoardError> {
        let mut buf = [0u8; 4096];
        let mut out = Vec::new();
        match self.stream.read(&mut buf) {
            Ok(0) => return Err(BoardError::Io("the device closed the link".into())),
            Ok(n) => self.dec.feed(&buf[..n], |r| out.push(r)),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(e) => return Err(BoardError::Io(e.to_string())),
        }
        Ok(out)
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
            for m in self.poll()? {
                match m {
                    Ok(DeviceMsg::Reply { id: rid, result }) if rid == id || rid == 0 => {
                        return result.map_err(BoardError::Device);
                    }
                    Ok(other) => self.log.push(other),
                    Err(e) => return Err(BoardError::Frame(e)),
                }
            }
        }
        Err(BoardError::Timeout(self.timeout))
    }

    /// One request and its reply.
    pub fn request(&mut self, cmd: Command) -> Result<Reply, BoardError> {
        let id = self.send(cmd)?;
        self.wait_reply(id)
    }

    /// Starts a grasp and waits for its end: the contact estimate, a fault or a stop. Polls
    /// the status meanwhile; `give_up` bounds the wait.
    pub fn grasp(&mut self, give_up: Duration) -> Result<Outcome, BoardError> {
        self.request(Command::Grasp)?;
        let t0 = Instant::now();
        let mut last_poll = Instant::now();
        let mut pending: Option<u16> = None;
        let mut contact = None;
        while t0.elapsed() < give_up {
            if last_poll.elapsed() >= POLL && pending.is_none() {
                pending = Some(self.send(Command::Status)?);
                last_poll = Instant::now();
            }
            for m in self.poll()? {
                match m {
                    Ok(DeviceMsg::Reply { id, result }) => {
                        if Some(id) == pending {
                            pending = None;
                        }
                        if let Err(e) = result {
                            return Err(BoardError::Device(e));
                        }
                    }
                    Ok(DeviceMsg::Contact(c)) => {
                        contact = Some(c);
                        self.log.push(DeviceMsg::Contact(c));
                    }
                    Ok(DeviceMsg::Event(ev)) => {
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
                    Ok(other) => self.log.push(other),
                    Err(e) => return Err(BoardError::Frame(e)),
                }
            }
        }
        Err(BoardError::Timeout(give_up))
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
        ParamId::Scene => Param::Scene(
            proto::SceneName::try_from(value)
                .map_err(|_| format!("{name} = {value}: at most 24 bytes"))?,
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert!(parse_param("delta_ta", "0.4").is_err());
        assert!(parse_param("delta_ta_nm", "x").is_err());
        assert!(is_serial("/dev/ttyACM0") && is_serial("COM3") && !is_serial("127.0.0.1:4321"));
        let e = Param::DeltaTaNm(9.0).check().unwrap_err();
        assert_eq!(
            describe(&e),
            "delta_ta_nm = 9 is outside the allowed range 0.05..=1.5"
        );
    }
}
