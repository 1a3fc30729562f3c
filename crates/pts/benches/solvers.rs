//! Host time per full estimate (contact configuration from θa,c + inversion) for each
//! solver variant, on the Table 2 measurement. `cargo xtask bench` reads the medians from
//! `target/criterion/estimate/<variant>/new/estimates.json`.
use criterion::{criterion_group, criterion_main, Criterion};
use pts::fixed::{Fx16, Fx24, Fx32};
use pts::table::{FreeTable, TableReal};
use pts::{Finger, Model};
use std::hint::black_box;
use std::time::Duration;

/// (θa,c, T_a,c, θa, T_a) of MODEL.md's Table 2 column.
const TABLE2: [f64; 4] = [-0.223771, 0.340821, -0.223771 + 0.0802814, 1.140821];

fn variant<R: TableReal>(
    c: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    name: &str,
) {
    let m = Model::<R>::new(&Finger::PAPER).unwrap();
    let t = FreeTable::<R>::new(&Finger::PAPER).unwrap();
    let v = TABLE2.map(R::from_f64);
    c.bench_function(name, |b| {
        b.iter(|| {
            m.estimate_two_point(
                black_box(v[0]),
                black_box(v[1]),
                black_box(v[2]),
                black_box(v[3]),
            )
        })
    });
    c.bench_function(format!("table_{name}"), |b| {
        b.iter(|| {
            t.estimate_two_point(
                black_box(v[0]),
                black_box(v[1]),
                black_box(v[2]),
                black_box(v[3]),
            )
        })
    });
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("estimate");
    g.warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1))
        .sample_size(30);
    variant::<f64>(&mut g, "f64");
    variant::<f32>(&mut g, "f32");
    variant::<Fx32>(&mut g, "Fx32");
    variant::<Fx24>(&mut g, "Fx24");
    variant::<Fx16>(&mut g, "Fx16");
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
