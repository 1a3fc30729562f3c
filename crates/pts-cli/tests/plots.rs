//! Every figure renders: a non-empty image of the stated size, in PNG and SVG.

use pts_cli::plot::{self, Size};
use std::path::PathBuf;
use std::process::Command;

fn out(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pts-plots-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

/// The PNG has the stated size and is not blank: many colours, and most of them are not white.
fn check_png(path: &PathBuf, w: u32, h: u32) {
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb8();
    assert_eq!((img.width(), img.height()), (w, h), "{}", path.display());
    let mut colours = std::collections::HashSet::new();
    let mut non_white = 0usize;
    for p in img.pixels() {
        colours.insert(p.0);
        if p.0 != [255, 255, 255] {
            non_white += 1;
        }
    }
    assert!(
        colours.len() > 20,
        "{}: {} colours",
        path.display(),
        colours.len()
    );
    let frac = non_white as f64 / f64::from(w * h);
    assert!(
        frac > 0.02,
        "{}: only {frac:.3} of the pixels are drawn",
        path.display()
    );
}

fn check_svg(path: &PathBuf, w: u32, h: u32) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.starts_with("<svg"), "{}", &text[..text.len().min(100)]);
    assert!(text.contains(&format!("width=\"{w}\"")) && text.contains(&format!("height=\"{h}\"")));
    assert!(text.matches("<polyline").count() + text.matches("<rect").count() > 5);
    assert!(text.contains("<text"));
}

#[test]
fn kc_curve_png_and_svg_through_the_cli() {
    for (name, size) in [("kc.png", "900x600"), ("kc.svg", "800x500")] {
        let p = out(name);
        let o = Command::new(env!("CARGO_BIN_EXE_pts"))
            .args([
                "plot",
                "kc",
                "--theta1-c",
                "1.2797,1.0",
                "--mark-kc",
                "9.965",
            ])
            .args(["--size", size, "-o", p.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let (w, h) = size.split_once('x').unwrap();
        let (w, h) = (w.parse().unwrap(), h.parse().unwrap());
        if name.ends_with("png") {
            check_png(&p, w, h);
        } else {
            check_svg(&p, w, h);
        }
    }
    // A wrong extension, a bad size and an impossible configuration are clear errors.
    for args in [
        vec!["plot", "kc", "-o", "/tmp/x.jpg"],
        vec!["plot", "kc", "--size", "10x10", "-o", "/tmp/x.png"],
        vec!["plot", "kc", "--theta1-c", "40", "-o", "/tmp/x.png"],
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_pts"))
            .args(&args)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{args:?}");
        assert_ne!(o.status.code(), Some(101), "panic on {args:?}");
    }
}

fn synthetic_signals() -> plot::Signals {
    // A grasp shape: approach ramp, contact at 1 s, a stiff step, hold.
    let n = 2000;
    let mut s = plot::Signals::default();
    let mut states = vec![];
    for i in 0..n {
        let t = i as f64 * 1e-3;
        let (th, ta, st) = if t < 1.0 {
            (-0.85 + 0.6 * t, 0.55 * t, "approach")
        } else if t < 1.5 {
            let d = (t - 1.0) / 0.5;
            (-0.25 + 0.08 * d, 0.55 + 0.8 * d, "step")
        } else {
            (-0.17, 1.35, "holding")
        };
        s.t_s.push(t);
        s.theta_a_rad.push(th);
        s.torque_nm.push(ta);
        states.push(st.to_string());
    }
    s.torque_ref_nm = Some(s.torque_nm.clone());
    s.state = Some(states);
    s.contact = Some((1.0, -0.25, 0.55));
    s.kc_hat = Some(10.0);
    s
}

#[test]
fn signals_png_and_svg() {
    let s = synthetic_signals();
    let size = Size {
        width: 1000,
        height: 750,
    };
    let p = out("signals.png");
    plot::signals(&p, size, "synthetic grasp", &s).unwrap();
    check_png(&p, 1000, 750);
    let p = out("signals.svg");
    plot::signals(&p, size, "synthetic grasp", &s).unwrap();
    check_svg(&p, 1000, 750);
    // Too little data is an error, not a panic or an empty picture.
    let short = plot::Signals {
        t_s: vec![0.0],
        theta_a_rad: vec![0.0],
        torque_nm: vec![0.0],
        ..Default::default()
    };
    assert!(plot::signals(&out("short.png"), size, "x", &short).is_err());
}

#[test]
fn heat_map_png_and_svg() {
    let cells = vec![
        (0.0, 10.0, 0.2, Some(1.7)),
        (0.0, 10.0, 0.8, Some(-8.5)),
        (5.0, 10.0, 0.2, Some(5.8)),
        (5.0, 10.0, 0.8, None),
        (5.0, 50.0, 0.8, Some(20.7)),
    ];
    let t = pts_cli::sim_cmd::table(&cells);
    // Radii come in cm (the sweep's unit) and are labelled in mm.
    assert_eq!(t.rows, vec![0.0, 50.0]);
    assert_eq!(t.cols, vec![0.2, 0.8]);
    assert_eq!(t.cells[0], vec![Some(1.7), Some(8.5)]);
    assert_eq!(t.cells[1], vec![Some(5.8), Some(20.7)]);
    let size = Size {
        width: 800,
        height: 600,
    };
    let p = out("heat.png");
    plot::heat_map(&p, size, "error", &t).unwrap();
    check_png(&p, 800, 600);
    let p = out("heat.svg");
    plot::heat_map(&p, size, "error", &t).unwrap();
    check_svg(&p, 800, 600);
}
