//! How much memory reading a trace takes: the peak while `read_text` + `read_csv` run, against the file's size. Issue 19 asks for at
//! most about twice the file.
//!
//! Measured as the process's resident high-water mark (Linux `/proc/self/status`, `VmHWM`)
//! over its resident size before: each shape runs in a process of its own (this test binary,
//! run again), and the files are large (tens of MB) so that the harness's own memory is
//! noise. Skipped elsewhere.

fn status_kb(key: &str) -> Option<usize> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn measure(name: &str, header: &str, row: impl Fn(usize) -> String, rows: usize) -> Option<f64> {
    let mut text = String::from(header);
    text.push('\n');
    for i in 0..rows {
        text.push_str(&row(i));
        text.push('\n');
    }
    let path = std::env::temp_dir().join(format!(
        "pts_trace_memory_{name}_{}.csv",
        std::process::id()
    ));
    std::fs::write(&path, &text).unwrap();
    let size = text.len();
    drop(text);
    // Reset the high-water mark to the current size (Linux ≥ 4.0), so each shape is measured
    // on its own.
    std::fs::write("/proc/self/clear_refs", "5").ok()?;
    let before = status_kb("VmRSS:")? * 1024;
    let t = pts_cli::estimate_cmd::read_text(&path).unwrap();
    let tr = pts_cli::trace::read_csv(&t, &|i| i).unwrap();
    let n = tr.len();
    let peak = (status_kb("VmHWM:")? * 1024).saturating_sub(before);
    drop((t, tr));
    let _ = std::fs::remove_file(&path);
    assert_eq!(n, rows);
    let ratio = peak as f64 / size as f64;
    println!("{name}: file {size} B, {rows} rows, peak {peak} B = {ratio:.2}x the file");
    Some(ratio)
}

fn narrow() -> Option<f64> {
    measure(
        "narrow",
        "t_s,theta_a_rad,torque_nm",
        |i| {
            format!(
                "{:.4},{:.8},{:.6}",
                i as f64 * 1e-4,
                -0.85 + i as f64 * 1e-7,
                0.1 + i as f64 * 1e-8
            )
        },
        500_000,
    )
}

fn wide() -> Option<f64> {
    measure(
        "wide",
        "t_s,theta_a_rad,torque_nm,torque_ref_nm,duty,state,encoder_count,current_code,true_theta_a_rad,true_torque_nm,true_contact,true_k_m",
        |i| {
            let x = i as f64;
            format!(
                "{},{},{},{},{},approach,{},{},{},{},free,0",
                x * 1e-4,
                -0.85 + x * 1.234_567e-7,
                0.1 + x * 3.21e-8,
                0.1 + x * 3.2e-8,
                0.05 + x * 1e-9,
                i % 65536,
                2048 + i % 7,
                -0.85 + x * 1.234_5e-7,
                0.1 + x * 3.3e-8
            )
        },
        150_000,
    )
}

const SHAPE: &str = "PTS_TRACE_MEMORY_SHAPE";

/// Two shapes: the narrow recorded trace (t, θa, T) and `pts sim --csv`'s full row, each in a
/// fresh process (this test binary run again for it): in one process the second shape would
/// reuse, uncounted, the resident pages the allocator kept from the first.
#[test]
fn reading_a_trace_holds_a_bounded_multiple_of_the_file() {
    if let Ok(shape) = std::env::var(SHAPE) {
        let r = if shape == "narrow" { narrow() } else { wide() };
        match r {
            Some(r) => println!("RATIO {r}"),
            None => println!("NOT MEASURED"),
        }
        return;
    }
    let exe = std::env::current_exe().unwrap();
    let run = |shape: &str| -> Option<f64> {
        let out = std::process::Command::new(&exe)
            .args([
                "--exact",
                "reading_a_trace_holds_a_bounded_multiple_of_the_file",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(SHAPE, shape)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        print!("{text}");
        assert!(out.status.success(), "{shape}: {text}");
        text.lines()
            .find_map(|l| l.strip_prefix("RATIO "))
            .and_then(|v| v.trim().parse().ok())
    };
    let (Some(narrow), Some(wide)) = (run("narrow"), run("wide")) else {
        println!("no /proc/self/status: not measured");
        return;
    };
    // About twice the file at most (issue 19): the text once, and the columns the file has
    // (f64 for its numbers) at most about as much again. Row structs (160 B a row) held
    // the narrow trace at 6.55x.
    assert!(wide < 2.1, "wide trace: {wide:.2}x the file");
    assert!(narrow < 2.1, "narrow trace: {narrow:.2}x the file");
}
