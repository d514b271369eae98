//! `examples/custom_base.rs` as a test: the seam's three traits over its line protocol, against
//! the simulated robot at the other end of an in-memory pipe, in virtual time.

#[allow(dead_code)]
#[path = "../examples/custom_base.rs"]
mod custom_base;

use custom_base::{serve, LineRobot};
use odocal::base::{BaseError, Drive, HeadingSource, ParamStore};
use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::sim::{NoiseModel, Simulator};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// A robot configured as nominal, truly `E_b` 0.976 and `E_d` 0.992, served on a pipe.
fn robot() -> (LineRobot, Arc<Mutex<Simulator>>) {
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let truth =
        WheelParams::from_ratios(&nominal, 0.976, 0.992, &SplitConvention::LeftNominal).unwrap();
    let noise = NoiseModel {
        compass_sigma_rad: 0.3f64.to_radians(),
        ..NoiseModel::default()
    };
    let sim = Arc::new(Mutex::new(
        Simulator::new(truth, nominal, noise, 7).unwrap(),
    ));
    let (host, far) = tokio::io::duplex(4096);
    tokio::spawn(serve(far, sim.clone()));
    (LineRobot::new(host, "test-robot"), sim)
}

#[tokio::test(start_paused = true)]
async fn the_example_base_calibrates_its_robot_over_the_line_protocol() {
    let (report, sim) = custom_base::calibrate_simulated_robot(3).await.unwrap();
    assert!(report.written && report.converged, "{:?}", report.warnings);
    let sim = sim.lock().unwrap();
    let (done, truth) = (*sim.configured(), *sim.truth());
    // What the report says is what the robot uses, and it is the truth to within the noise.
    assert_eq!(done, report.final_params);
    assert!(
        (done.wheelbase_m / truth.wheelbase_m - 1.0).abs() < 2e-3,
        "{done:?} against {truth:?}"
    );
    assert!(
        (done.right_wheel_diameter_m / truth.right_wheel_diameter_m - 1.0).abs() < 1e-3,
        "{done:?} against {truth:?}"
    );
    // Both streams were polled over the link, and the heading along the legs was used.
    let run = &report.rounds[0].runs[0];
    assert!(
        run.travel_samples > 20 && run.heading_samples > 20,
        "{run:?}"
    );
    assert!(report.rounds[0].chosen.method.needs_leg_headings());
    assert!(report.verification.len() >= 4);
}

#[tokio::test(start_paused = true)]
async fn headings_are_never_returned_twice_and_motions_wait_for_the_robot() {
    let (robot, sim) = robot();
    let a = HeadingSource::read(&robot).await.unwrap();
    let b = HeadingSource::read(&robot).await.unwrap();
    assert!(b.time_s > a.time_s, "{a:?} then {b:?}");
    // Polled four times per compass reading, the stream still gives each reading once, and
    // none is lost: 50 Hz for one second.
    let mut stream = robot
        .stream(Duration::from_millis(5))
        .await
        .unwrap()
        .unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let mut times = Vec::new();
    while let Ok(s) = stream.try_recv() {
        times.push(s.time_s);
    }
    drop(stream);
    assert!(times.windows(2).all(|w| w[1] > w[0]), "{times:?}");
    assert!((49..=51).contains(&times.len()), "{times:?}");
    // A motion returns once the robot has done it: 0.5 m at 0.25 m/s takes two seconds.
    let start = tokio::time::Instant::now();
    robot.move_straight(0.5, 0.25).await.unwrap();
    let took = start.elapsed();
    assert!(
        took >= Duration::from_secs(2) && took < Duration::from_millis(2100),
        "{took:?}"
    );
    let x = sim.lock().unwrap().pose().x_m;
    assert!((x - 0.5).abs() < 0.01, "the robot is at {x} m");
}

#[tokio::test(start_paused = true)]
async fn the_robot_stops_on_its_watchdog_and_refusals_are_typed() {
    let (robot, sim) = robot();
    robot
        .arm_watchdog(Duration::from_millis(300))
        .await
        .unwrap();
    // A limit that is no limit is refused here, before anything is sent.
    for bad in [0.0, -0.2, f64::NAN, f64::INFINITY] {
        match robot.move_straight(1.0, bad).await {
            Err(BaseError::InvalidArgument { reason, .. }) => assert!(reason.contains("speed")),
            other => panic!("{bad}: {other:?}"),
        }
    }
    assert!(!robot.encoders().await.unwrap().3);
    // A second motion while one is under way is refused by the robot, not garbled.
    robot.ok("MOVE 2 0.5").await.unwrap();
    match robot.ok("MOVE 1 0.5").await {
        Err(BaseError::Refused { reason, .. }) => assert_eq!(reason, "busy"),
        other => panic!("{other:?}"),
    }
    // The host falls silent for a second: the robot stops 0.3 s after its last line.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let (.., moving) = robot.encoders().await.unwrap();
    assert!(!moving);
    let x = sim.lock().unwrap().pose().x_m;
    assert!((0.1..0.2).contains(&x), "the robot drove {x} m");
    // The emergency stop needs no answer and stops a motion at once.
    robot.ok("MOVE 2 0.5").await.unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    robot.emergency_stop();
    let (.., moving) = robot.encoders().await.unwrap();
    assert!(!moving);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let x2 = sim.lock().unwrap().pose().x_m;
    assert!((x2 - x - 0.1).abs() < 0.01, "0.1 m more, not {}", x2 - x);
    // Parameters round-trip exactly; what was saved reads back.
    let p = WheelParams::nominal(0.151, 0.3812345678, 4096.0);
    assert_eq!(ParamStore::write(&robot, &p).await.unwrap(), p);
    robot.commit().await.unwrap();
    assert_eq!(robot.read_committed().await.unwrap(), Some(p));
}
