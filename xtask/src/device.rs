//! The device-mode end-to-end stage of `cargo xtask test`: the QEMU firmware built with
//! feature `device` and `pts board` over its UART socket. Bad input first (malformed frame,
//! corrupted checksum, unknown command, out-of-range value: typed errors), then a stop in
//! mid-approach (bridge off within one control period), a host that disconnects mid-grasp
//! (bridge off, fault reported), then three grasps with different scenes, ΔT_a and both
//! estimators in the same power-up, each estimate against the host runner's with the same
//! scene and settings.

use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::log::{self, int};
use crate::qemu::{self, Frame};
use crate::util::{self, Res};

/// Tolerance of a device-mode estimate against the host run of the same grasp, × l2.
const K2_TOL_REL_L2: f64 = 1e-4;

/// The grasps: (scene, ΔT_a in N·m, estimator).
const GRASPS: &[(&str, &str, &str)] = &[
    ("table2", "0.8", "path-fit"),
    ("cyl10_k2_20", "0.6", "two-point"),
    ("vertex_k2_30", "1.0", "two-point"),
];

/// Seconds a grasp may take in QEMU (wall) before the stage gives up.
const GRASP_WALL_S: &str = "400";

struct Session {
    elf: PathBuf,
    log: PathBuf,
    pts: PathBuf,
    addr: String,
}

impl Session {
    /// `pts board --json ARGS`: (exit status, stdout parsed as JSON, stderr).
    fn board(&self, args: &[&str]) -> Res<(i32, Value, String)> {
        let out = Command::new(&self.pts)
            .args(["board", "--connect", &self.addr, "--json"])
            .args(args)
            .output()
            .map_err(|e| format!("cannot run {}: {e}", self.pts.display()))?;
        let stdout = String::from_utf8_lossy(&out.stdout).to_string();
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        let v =
            serde_json::from_str(stdout.lines().last().unwrap_or("null")).unwrap_or(Value::Null);
        println!(
            "pts board {} -> exit {:?}: {}{}",
            args.join(" "),
            out.status.code(),
            stdout.trim(),
            if stderr.is_empty() {
                String::new()
            } else {
                format!(" / {}", stderr.trim())
            }
        );
        Ok((out.status.code().unwrap_or(-1), v, stderr))
    }

    /// `pts board` that must succeed.
    fn ok(&self, args: &[&str]) -> Res<Value> {
        match self.board(args)? {
            (0, v, _) => Ok(v),
            (c, v, e) => Err(format!(
                "pts board {args:?} exited {c}: {v} {e}",
                args = args.join(" ")
            )),
        }
    }

    /// The device's reply to raw bytes (`pts board raw HEX`).
    fn raw(&self, bytes: &[u8]) -> Res<Value> {
        let hex: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        Ok(self.board(&["raw", &hex])?.1)
    }

    fn frames(&self) -> Res<Vec<Frame>> {
        qemu::decode_file(&self.elf, &self.log)
    }

    fn state(&self) -> Res<(String, bool, Value)> {
        let v = self.ok(&["status"])?;
        let st = &v["reply"]["Status"];
        let state = match &st["state"] {
            Value::String(s) => s.clone(),
            Value::Object(o) => o.keys().next().cloned().unwrap_or_default(),
            other => other.to_string(),
        };
        Ok((state, st["bridge_on"].as_bool().unwrap_or(true), v))
    }
}

/// A request frame with these postcard body bytes (after the version byte), CRC appended.
fn frame_with_body(body: &[u8], corrupt_crc: bool) -> Vec<u8> {
    // Encode a real request, then rebuild its content with our body: the CRC is proto's.
    let mut raw = vec![proto::VERSION];
    raw.extend_from_slice(body);
    let crc = crc16_x25(&raw);
    let crc = if corrupt_crc { crc ^ 0x0101 } else { crc };
    raw.extend(crc.to_le_bytes());
    let mut out = cobs_encode(&raw);
    out.push(0);
    out
}

/// CRC-16/X.25 written out (an independent reference of what proto uses).
fn crc16_x25(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= u16::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x8408
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// COBS without the delimiter (an independent reference).
fn cobs_encode(data: &[u8]) -> Vec<u8> {
    let mut out = vec![0];
    let mut code_at = 0;
    let mut code = 1u8;
    for &b in data {
        if b == 0 {
            out[code_at] = code;
            code_at = out.len();
            out.push(0);
            code = 1;
        } else {
            out.push(b);
            code += 1;
            if code == 0xFF {
                out[code_at] = code;
                code_at = out.len();
                out.push(0);
                code = 1;
            }
        }
    }
    out[code_at] = code;
    out
}

/// The host runner's estimate of a grasp (µm), and the finger's l2 (µm).
struct HostEstimate {
    k2_um: i64,
    l2_um: f64,
    /// σ of k2 (path fit).
    sigma_um: Option<i64>,
    /// The two-point reference beside the path fit.
    two_point_k2_um: Option<i64>,
}

/// The host runner's estimate of the same grasp.
fn host_estimate(scene: &str, dta: &str, estimator: &str) -> Res<HostEstimate> {
    let (out, _) = util::output_code(
        util::cargo()
            .args([
                "run",
                "-q",
                "-p",
                "finger-fw",
                "--",
                "simulate",
                "--scene",
                scene,
                "--dta",
                dta,
                "--estimator",
                estimator,
            ])
            // Built like the device firmware (a path-fit build: both estimators at run time).
            .env("FINGER_FW_ESTIMATOR", "path-fit"),
    )?;
    let l2 = out
        .lines()
        .find(|l| l.starts_with("BOOT"))
        .and_then(|l| int(l, "l2_um"))
        .ok_or("host run: no BOOT line")? as f64;
    let estimated = out
        .lines()
        .rfind(|l| l.starts_with("E Estimated"))
        .ok_or_else(|| format!("host run of {scene} gave no estimate"))?;
    Ok(HostEstimate {
        k2_um: int(estimated, "k2_um").ok_or_else(|| format!("host run of {scene}: no k2"))?,
        l2_um: l2,
        sigma_um: int(estimated, "k2_sigma_um"),
        two_point_k2_um: int(estimated, "two_point_k2_um"),
    })
}

/// A TCP port free on the loopback interface now (for QEMU's UART socket).
pub fn free_port() -> Res<u16> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
    Ok(l.local_addr().map_err(|e| e.to_string())?.port())
}

/// Builds the device firmware (path-fit build: both estimators at run time).
pub fn build() -> Res<PathBuf> {
    let mut cmd = util::cargo();
    cmd.args([
        "build",
        "--release",
        "-p",
        "finger-fw",
        "--target",
        qemu::TARGET,
        "--no-default-features",
        "--features",
        "qemu,device",
    ])
    .env("FINGER_FW_SCENE", "table2")
    .env("FINGER_FW_ESTIMATOR", "path-fit")
    .env("FINGER_FW_INJECT", "");
    util::run(&mut cmd)?;
    let built = util::root()
        .join("target")
        .join(qemu::TARGET)
        .join("release")
        .join("finger-fw");
    // Kept apart: the next stage's build overwrites the one above.
    let elf = util::root().join("target").join("finger-fw-device.elf");
    std::fs::copy(&built, &elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    Ok(elf)
}

/// The stage.
pub fn check() -> Res {
    let elf = build()?;
    let pts = util::build_pts()?;
    util::run(util::cargo().args(["build", "-q", "-p", "finger-fw"]))?;
    let port = free_port()?;
    let s = Session {
        elf,
        log: util::root().join("target").join("finger-fw-device.defmt"),
        pts,
        addr: format!("127.0.0.1:{port}"),
    };
    let mut child = qemu::spawn_device(&s.elf, port, &s.log)?;
    let r = session(&s);
    let _ = child.kill();
    let _ = child.wait();
    if let Ok(frames) = s.frames() {
        for f in frames.iter().filter(|f| !f.msg.starts_with("P ")) {
            println!("{}", log::show(f));
        }
    }
    r
}

fn session(s: &Session) -> Res {
    let t0 = Instant::now();
    // The socket is there once QEMU started.
    let hello = loop {
        match s.board(&["hello"]) {
            Ok((0, v, _)) => break v,
            _ if t0.elapsed() < Duration::from_secs(20) => {
                std::thread::sleep(Duration::from_millis(200))
            }
            other => return Err(format!("no hello from the device: {other:?}")),
        }
    };
    let mut errs = Vec::new();
    if hello["reply"]["Hello"]["version"].as_u64() != Some(u64::from(proto::VERSION)) {
        errs.push(format!("hello: {hello}"));
    }
    errs.extend(bad_input(s)?);
    errs.extend(stop_mid_approach(s)?);
    errs.extend(disconnect_mid_grasp(s)?);
    errs.extend(three_grasps(s)?);
    errs.extend(record_and_replay(s)?);
    errs.extend(calibrate_on_device(s)?);
    errs.extend(watch_lines(s)?);
    let (_, _, v) = s.state()?;
    let grasps = v["reply"]["Status"]["grasps"].as_u64();
    let boots = s
        .frames()?
        .iter()
        .filter(|f| f.msg.starts_with("BOOT"))
        .count();
    if grasps != Some(6) || boots != 1 {
        errs.push(format!(
            "one power-up expected: {boots} boots, {grasps:?} grasps (expected 6)"
        ));
    }
    errs.extend(store_and_reboot(s)?);
    println!("device session: {:.1} s", t0.elapsed().as_secs_f64());
    if errs.is_empty() {
        Ok(())
    } else {
        Err(errs.join("\n"))
    }
}

/// Bad input: each a typed error, the device still answering.
fn bad_input(s: &Session) -> Res<Vec<String>> {
    let mut errs = Vec::new();
    // One frame (one delimiter, so exactly one reply): its COBS code promises four bytes and
    // only two follow before the delimiter.
    let malformed = s.raw(&[0x05, 0xC8, 0x01, 0x00])?;
    if malformed["device_error"]["BadFrame"].is_null() {
        errs.push(format!("malformed frame: {malformed}"));
    }
    // Request id 7 (varint 07), command Status (tag 1): the right body with a wrong CRC.
    let bad_crc = s.raw(&frame_with_body(&[0x07, 0x01], true))?;
    if bad_crc["device_error"]["BadFrame"]["Checksum"].is_null() {
        errs.push(format!("corrupted checksum: {bad_crc}"));
    }
    let good = s.raw(&frame_with_body(&[0x07, 0x01], false))?;
    if good["reply"]["Status"].is_null() || good["id"].as_u64() != Some(7) {
        errs.push(format!("hand-built status request: {good}"));
    }
    let unknown = s.raw(&frame_with_body(&[0x09, 0xC8, 0x01], false))?;
    if unknown["device_error"]["UnknownCommand"]["tag"].as_u64() != Some(200)
        || unknown["id"].as_u64() != Some(9)
    {
        errs.push(format!("unknown command: {unknown}"));
    }
    let (code, _, stderr) = s.board(&["set", "delta_ta_nm", "9"])?;
    if code != 1 || !stderr.contains("delta_ta_nm = 9 is outside the allowed range 0.05..=1.5") {
        errs.push(format!("out-of-range ΔT_a: exit {code}, {stderr}"));
    }
    let (code, v, _) = s.board(&["set", "scene", "no_such_scene"])?;
    if code != 1 || v["ok"] != Value::Bool(false) {
        errs.push(format!("unknown scene accepted: {v}"));
    }
    Ok(errs)
}

/// Stop in mid-approach: the bridge off within one control period; store refused while it is on.
fn stop_mid_approach(s: &Session) -> Res<Vec<String>> {
    let mut errs = Vec::new();
    // Stop in mid-approach.
    s.ok(&["set", "scene", "table2"])?;
    s.ok(&["grasp", "--no-wait"])?;
    let mut seen_approach = false;
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(60) {
        let (state, bridge_on, _) = s.state()?;
        if state == "Approach" && bridge_on {
            seen_approach = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    if !seen_approach {
        errs.push("the grasp never showed Approach with the bridge on".into());
    }
    // Erasing flash stalls the CPU on the board: store is refused with the bridge on.
    let (code, v, _) = s.board(&["store"])?;
    if code != 1 || v["error"].as_str().is_none_or(|e| !e.starts_with("busy")) {
        errs.push(format!("store with the bridge on: exit {code}, {v}"));
    }
    s.ok(&["stop"])?;
    let (state, bridge_on, _) = s.state()?;
    if state != "Stopped" || bridge_on {
        errs.push(format!("after stop: state {state}, bridge_on {bridge_on}"));
    }
    match s
        .frames()?
        .iter()
        .rfind(|f| f.msg.starts_with("STOP requested"))
    {
        Some(f) => {
            let rx = int(&f.msg, "requested_tick").unwrap_or(i64::MAX);
            let off = int(&f.msg, "off_tick").unwrap_or(i64::MAX);
            println!("stop: requested at tick {rx}, bridge off at tick {off}");
            if off.saturating_sub(rx) > 1 || off < rx {
                errs.push(format!(
                    "stop took {} control periods (more than one)",
                    off - rx
                ));
            }
        }
        None => errs.push("no STOP line in the firmware log".into()),
    }
    Ok(errs)
}

/// A host that disconnects in mid-grasp: the device switches the bridge off by itself and
/// latches the fault until a stop acknowledges it.
fn disconnect_mid_grasp(s: &Session) -> Res<Vec<String>> {
    let mut errs = Vec::new();
    s.ok(&["grasp", "--no-wait"])?;
    let t = Instant::now();
    let mut lost = false;
    while t.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(500));
        if s.frames()?.iter().any(|f| f.msg.starts_with("HOST lost")) {
            lost = true;
            break;
        }
    }
    let (state, bridge_on, v) = s.state()?;
    if !lost || bridge_on || v["reply"]["Status"]["state"]["Fault"]["kind"] != "HostLost" {
        errs.push(format!(
            "disconnect mid-grasp: HOST lost logged {lost}, state {state}, bridge_on {bridge_on}"
        ));
    }
    let (code, v, _) = s.board(&["grasp", "--no-wait"])?;
    if code != 1
        || v["error"]
            .as_str()
            .is_none_or(|e| !e.contains("fault latched"))
    {
        errs.push(format!("grasp with a latched fault: exit {code}, {v}"));
    }
    s.ok(&["stop"])?;
    Ok(errs)
}

/// Three grasps in the same power-up, each k2 (and σ, two-point k2) equal to the host
/// runner's with the same settings, each released back to rest.
fn three_grasps(s: &Session) -> Res<Vec<String>> {
    let mut errs = Vec::new();
    // Three grasps in the same power-up.
    for (scene, dta, est) in GRASPS {
        s.ok(&["set", "scene", scene])?;
        s.ok(&["set", "delta_ta_nm", dta])?;
        s.ok(&["set", "estimator", est])?;
        let t = Instant::now();
        let v = s.ok(&["grasp", "--grasp-timeout", GRASP_WALL_S])?;
        let k2_dev = v["contact"]["k2_um"]
            .as_i64()
            .ok_or_else(|| format!("{scene}: no k2 in {v}"))?;
        let dev_est = v["contact"]["estimator"].as_str().unwrap_or("");
        let host = host_estimate(scene, dta, est)?;
        let (k2_host, l2) = (host.k2_um, host.l2_um);
        let d = (k2_dev - k2_host).abs() as f64;
        println!(
            "grasp {scene} ΔT_a {dta} N·m {est}: k2 device {k2_dev} µm, host {k2_host} µm, |Δ| {d} µm (tolerance {:.1} µm), {:.1} s",
            K2_TOL_REL_L2 * l2,
            t.elapsed().as_secs_f64()
        );
        if d > K2_TOL_REL_L2 * l2 {
            errs.push(format!(
                "{scene} ΔT_a {dta} {est}: device k2 {k2_dev} µm vs host {k2_host} µm"
            ));
        }
        // A path fit reports its σ and the paper's two-point k2 beside it, as the host does.
        if *est == "path-fit" {
            for (field, host_v) in [
                ("sigma_um", host.sigma_um),
                ("two_point_k2_um", host.two_point_k2_um),
            ] {
                let dev_v = v["contact"][field].as_i64();
                let close = matches!((dev_v, host_v), (Some(a), Some(b))
                    if ((a - b).abs() as f64) <= K2_TOL_REL_L2 * l2);
                println!("  {field}: device {dev_v:?}, host {host_v:?}");
                if !close {
                    errs.push(format!(
                        "{scene} {est}: {field} device {dev_v:?} vs host {host_v:?}"
                    ));
                }
            }
        }
        let want = if *est == "path-fit" {
            "PathFit"
        } else {
            "TwoPoint"
        };
        if dev_est != want {
            errs.push(format!("{scene}: the device ran {dev_est}, asked {want}"));
        }
        let r = s.ok(&["release"])?;
        let (state, bridge_on, _) = s.state()?;
        if state != "Idle" || bridge_on {
            errs.push(format!("after release: {state}, bridge_on {bridge_on}"));
        }
        // Opened back to rest (the gear does not let the springs do it alone).
        let theta = r["released"]["theta_a_urad"].as_f64().map(|t| t * 1e-6);
        let rest = s.ok(&["drive"])?["reply"]["Drive"]["theta_a_rest_rad"].as_f64();
        match (theta, rest) {
            (Some(t), Some(rest)) if (t - rest).abs() <= RELEASE_REST_TOL_RAD => {
                println!("  released at θa {t:.4} rad, rest {rest:.4} rad")
            }
            _ => errs.push(format!(
                "{scene}: released at θa {theta:?} rad, rest {rest:?} rad (tolerance {RELEASE_REST_TOL_RAD})"
            )),
        }
    }
    Ok(errs)
}

/// The live view, non-interactive: summary lines, and the telemetry rate restored after.
fn watch_lines(s: &Session) -> Res<Vec<String>> {
    let mut errs = Vec::new();
    let before = s.state()?.2["reply"]["Status"]["settings"]["telemetry_hz"].clone();
    let (code, _, lines) = s.board(&["watch", "--seconds", "1.5", "--rate", "1000"])?;
    let after = s.state()?.2["reply"]["Status"]["settings"]["telemetry_hz"].clone();
    if code != 0 || !lines.contains("state idle") || before != after {
        errs.push(format!(
            "watch: exit {code}, telemetry_hz {before} -> {after}, lines {lines}"
        ));
    }
    Ok(errs)
}

/// A grasp recorded at every control tick (`pts board record`, seated, on a 2 N·m/s ramp and
/// with other settings unlike the defaults) replays through `pts estimate --trace` to the
/// device's own k2, exactly: the replay's controller takes the recording's settings, so a
/// replay that ran today's default (no seating, 4 N·m/s) instead would not.
fn record_and_replay(s: &Session) -> Res<Vec<String>> {
    let mut errs = vec![];
    s.ok(&["set", "scene", "cyl10_k2_20"])?;
    s.ok(&["set", "delta_ta_nm", "0.7"])?;
    s.ok(&["set", "estimator", "two-point"])?;
    s.ok(&["set", "step_ramp_nm_per_s", "2"])?;
    s.ok(&["set", "seating", "on"])?;
    let csv = util::root().join("target").join("device-record.csv");
    let csv_s = csv.display().to_string();
    let t = Instant::now();
    let v = s.ok(&["record", "-o", &csv_s, "--grasp-timeout", GRASP_WALL_S])?;
    let k2_dev = v["contact"]["k2_um"]
        .as_i64()
        .ok_or_else(|| format!("record: no k2 in {v}"))?;
    s.ok(&["release"])?;
    // Back to the build's defaults for what follows.
    s.ok(&["set", "step_ramp_nm_per_s", "4"])?;
    s.ok(&["set", "seating", "off"])?;
    let meta = std::fs::read_to_string(&csv)
        .map_err(|e| format!("{csv_s}: {e}"))?
        .lines()
        .find(|l| l.contains("source=pts-board-record"))
        .map(str::to_string)
        .unwrap_or_default();
    for want in ["seating=1", "step_ramp_nm_per_s=2"] {
        if !meta.split_whitespace().any(|w| w == want) {
            errs.push(format!(
                "recorded grasp: no {want} in its settings line: {meta}"
            ));
        }
    }
    let out = Command::new(&s.pts)
        .args(["estimate", "--trace", &csv_s, "--json"])
        .output()
        .map_err(|e| format!("cannot run pts estimate: {e}"))?;
    let text = String::from_utf8_lossy(&out.stdout);
    let est: Value = serde_json::from_str(text.lines().last().unwrap_or("null"))
        .map_err(|e| format!("pts estimate --json: {e}: {text}"))?;
    let k2_replay = est["contacts"][0]["k2"]
        .as_f64()
        .map(|k| (k * 1e6).round() as i64);
    let rows = est["rows"].as_u64().unwrap_or(0);
    let l2_um = s
        .frames()?
        .iter()
        .find(|f| f.msg.starts_with("BOOT"))
        .and_then(|f| int(&f.msg, "l2_um"))
        .ok_or("no l2_um in the firmware's BOOT line")? as f64;
    println!(
        "record: {rows} ticks in {csv_s} ({:.1} s); k2 device {k2_dev} µm, replay {k2_replay:?} µm, exact replay {}",
        t.elapsed().as_secs_f64(),
        est["exact_replay"]
    );
    match k2_replay {
        Some(k) if ((k - k2_dev).abs() as f64) <= K2_TOL_REL_L2 * l2_um => {}
        _ => errs.push(format!(
            "recorded grasp: device k2 {k2_dev} µm, `pts estimate --trace` {est}"
        )),
    }
    if est["exact_replay"] != Value::Bool(true) || est["method"] != "two-point" {
        errs.push(format!(
            "recorded grasp not replayed exactly with its estimator: {est}"
        ));
    }
    Ok(errs)
}

/// How far from the rest angle a release may leave the finger (rad): the controller's end
/// band (0.03) and the coasting after the bridge goes off.
const RELEASE_REST_TOL_RAD: f64 = 0.05;

/// The calibration sweep on the device: stopped in mid-sweep (bridge off, state stopped),
/// then run whole with `pts board calibrate`, whose identification must agree within each
/// parameter's σ with `pts calibrate` on the host's simulation of the firmware's sweep
/// (`--simulate --firmware`: the same loop on the same plant, no QEMU).
fn calibrate_on_device(s: &Session) -> Res<Vec<String>> {
    let mut errs = vec![];
    s.ok(&["set", "scene", "table2"])?;
    s.ok(&["calibrate", "--no-wait"])?;
    let t = Instant::now();
    let mut sweeping = false;
    while t.elapsed() < Duration::from_secs(60) {
        let (state, bridge_on, _) = s.state()?;
        if state == "Sweeping" && bridge_on {
            sweeping = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    if !sweeping {
        errs.push("calibrate: the device never showed Sweeping with the bridge on".into());
    }
    s.ok(&["stop"])?;
    let (state, bridge_on, _) = s.state()?;
    if state != "Stopped" || bridge_on {
        errs.push(format!(
            "stop mid-sweep: state {state}, bridge_on {bridge_on}"
        ));
    }

    let target = util::root().join("target");
    let dev_csv = target.join("device-sweep.csv").display().to_string();
    let host_csv = target.join("host-sweep.csv").display().to_string();
    let t = Instant::now();
    let dev = s.ok(&["calibrate", "--trace", &dev_csv, "--sweep-timeout", "900"])?;
    println!("calibrate: device sweep {:.1} s", t.elapsed().as_secs_f64());
    let (state, bridge_on, _) = s.state()?;
    if state != "Idle" || bridge_on {
        errs.push(format!(
            "after the sweep: state {state}, bridge_on {bridge_on}"
        ));
    }
    let pts = |args: &[&str]| -> Res<String> {
        let out = Command::new(&s.pts)
            .args(args)
            .output()
            .map_err(|e| format!("cannot run pts: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "pts {}: {}",
                args.join(" "),
                String::from_utf8_lossy(&out.stderr)
            ));
        }
        Ok(String::from_utf8_lossy(&out.stdout).to_string())
    };
    pts(&[
        "calibrate",
        "--simulate",
        "--firmware",
        "--trace",
        &host_csv,
    ])?;
    let text = pts(&["calibrate", "--trace", &host_csv, "--json"])?;
    let host: Value = serde_json::from_str(text.lines().last().unwrap_or("null"))
        .map_err(|e| format!("pts calibrate --json: {e}: {text}"))?;
    let (Some(dev_p), Some(host_p)) = (dev["params"].as_array(), host["params"].as_array()) else {
        return Err(format!("calibrate: no parameters in {dev} / {host}"));
    };
    let mut compared = 0;
    for h in host_p {
        let name = h["name"].as_str().unwrap_or("?");
        let (Some(hv), Some(sigma)) = (h["value"].as_f64(), h["sigma"].as_f64()) else {
            continue;
        };
        let dv = dev_p
            .iter()
            .find(|d| d["name"] == h["name"])
            .and_then(|d| d["value"].as_f64());
        println!("  {name}: device {dv:?}, host {hv} ± {sigma}");
        compared += 1;
        match dv {
            Some(dv) if (dv - hv).abs() <= sigma => {}
            _ => errs.push(format!(
                "calibrate {name}: device {dv:?} vs host {hv} (σ {sigma})"
            )),
        }
    }
    if compared < 5 {
        errs.push(format!(
            "calibrate: only {compared} parameters identified: {host}"
        ));
    }
    Ok(errs)
}

/// ΔT_a stored before the reboot (N·m); differs from the build's default and the value set
/// after the store, so only the stored record can give it back.
const STORED_DTA: f64 = 0.55;

/// ΔT_a of the parameter `get` reply (N·m).
fn dta_of(v: &Value) -> Option<f64> {
    v["reply"]["Param"]["DeltaTaNm"].as_f64()
}

/// Store, change, load gives the stored value back; store, change, reboot (a system reset:
/// the RAM store survives it) boots with the stored value.
fn store_and_reboot(s: &Session) -> Res<Vec<String>> {
    let mut errs = Vec::new();
    // (settings_source, settings_changed) of a status reply.
    let source = |s: &Session| -> Res<(Value, Value)> {
        let v = s.state()?.2;
        let st = &v["reply"]["Status"];
        Ok((
            st["settings_source"].clone(),
            st["settings_changed"].clone(),
        ))
    };
    let dta = STORED_DTA.to_string();
    s.ok(&["set", "delta_ta_nm", &dta])?;
    // Nothing stored since power-up (QEMU's store starts empty), and changed by the session.
    let (src, changed) = source(s)?;
    if src["Defaults"]["why"] != "Empty" || changed != Value::Bool(true) {
        errs.push(format!(
            "status before any store: source {src}, changed {changed}"
        ));
    }
    s.ok(&["store"])?;
    let (src, changed) = source(s)?;
    if src != "Store" || changed != Value::Bool(false) {
        errs.push(format!(
            "status after store: source {src}, changed {changed}"
        ));
    }
    s.ok(&["set", "delta_ta_nm", "0.9"])?;
    s.ok(&["load"])?;
    let got = dta_of(&s.ok(&["get", "delta_ta_nm"])?);
    if got != Some(STORED_DTA) {
        errs.push(format!(
            "load after store: ΔT_a {got:?}, stored {STORED_DTA}"
        ));
    }
    s.ok(&["set", "delta_ta_nm", "0.9"])?;
    let boots = |s: &Session| -> Res<usize> {
        Ok(s.frames()?
            .iter()
            .filter(|f| f.msg.starts_with("BOOT"))
            .count())
    };
    let before = boots(s)?;
    s.ok(&["reboot"])?;
    let t = Instant::now();
    while boots(s)? == before && t.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(200));
    }
    let hello = loop {
        match s.board(&["hello"]) {
            Ok((0, v, _)) => break Some(v),
            _ if t.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(200))
            }
            _ => break None,
        }
    };
    if boots(s)? != before + 1 || hello.is_none() {
        errs.push(format!(
            "reboot: {} boots after it (expected {}), hello {hello:?}",
            boots(s)?,
            before + 1
        ));
        return Ok(errs);
    }
    let got = dta_of(&s.ok(&["get", "delta_ta_nm"])?);
    let src = s
        .frames()?
        .iter()
        .rfind(|f| f.msg.starts_with("SETTINGS source="))
        .map(|f| f.msg.clone());
    println!("after reboot: ΔT_a {got:?} N·m, log {src:?}");
    let (status_src, changed) = source(s)?;
    if status_src != "Store" || changed != Value::Bool(false) {
        errs.push(format!(
            "status after reboot: source {status_src}, changed {changed}"
        ));
    }
    if got != Some(STORED_DTA) || !src.as_deref().is_some_and(|m| m.contains("source=store")) {
        errs.push(format!(
            "reboot: ΔT_a {got:?} (stored {STORED_DTA}), log {src:?}"
        ));
    }
    Ok(errs)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hand-written references agree with proto's encoder on a real request.
    #[test]
    fn hand_built_frames_match_proto() {
        let mut out = [0u8; proto::MAX_FRAME];
        let n = proto::encode(
            &proto::Request {
                id: 7,
                cmd: proto::Command::Status,
            },
            &mut out,
        )
        .unwrap();
        assert_eq!(frame_with_body(&[0x07, 0x01], false), out[..n].to_vec());
        assert_eq!(crc16_x25(b"123456789"), 0x906E);
    }
}
