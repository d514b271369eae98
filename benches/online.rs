//! Online estimator throughput: one filter update = an encoder prediction, plus a heading
//! update every 10th step (100 Hz encoders, 10 Hz compass). Target (issue 6): ≥ 1 000 000
//! updates per second on one core.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use odocal::calibration::online::{OnlineConfig, OnlineEstimator};
use odocal::kinematics::WheelParams;

fn bench(c: &mut Criterion) {
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let steps = 10_000u64;
    let mut g = c.benchmark_group("online_ekf");
    g.throughput(Throughput::Elements(steps));
    g.bench_function("predict_and_heading_updates", |b| {
        b.iter(|| {
            let mut f = OnlineEstimator::new(OnlineConfig::new(nominal)).expect("valid config");
            f.update_heading(0.0);
            let mut heading = 0.0;
            for i in 0..steps {
                let (l, r) = if (i / 500) % 2 == 0 {
                    (80.0, 95.0)
                } else {
                    (90.0, 90.0)
                };
                f.predict_counts(l, r);
                heading += 0.0012;
                if i % 10 == 9 {
                    f.update_heading(heading);
                }
            }
            std::hint::black_box(f.state())
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
