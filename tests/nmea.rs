//! NMEA compasses on real pseudo-terminals: what a port held before it was opened is not a
//! reading, and `odocal heading --samples 5` reads compasses from 0.5 to 50 Hz (with CR LF,
//! LF or CR alone).

mod common;

use odocal::base::HeadingSource;
use odocal::nmea::NmeaCompass;
use std::sync::Arc;
use std::time::Duration;

/// Sentences queued on the port before it was opened (a compass that has been talking all
/// along) are not readings: the first reading is one the compass sent after. (On one
/// thread the reader meets the backlog only after the first read has begun waiting.)
#[tokio::test]
async fn what_was_queued_before_opening_is_not_a_reading() {
    use std::sync::atomic::{AtomicU64, Ordering};
    let heading = Arc::new(AtomicU64::new(1.0f64.to_bits()));
    let h = heading.clone();
    let cfg = odocal::mock::nmea::MockCompassConfig {
        hz: 1.0,
        ..Default::default()
    };
    let pty = odocal::mock::nmea::spawn_pty(
        cfg,
        Arc::new(move || Some(f64::from_bits(h.load(Ordering::SeqCst)))),
    )
    .unwrap();
    // Two sentences of the old heading (at 0 and 1 s) pile up on the port; the robot then
    // turns, and the port is opened before the compass's next sentence.
    tokio::time::sleep(Duration::from_millis(1300)).await;
    heading.store((-2.0f64).to_bits(), Ordering::SeqCst);
    let compass = NmeaCompass::open(&pty.path, 115_200, Duration::from_secs(1)).unwrap();
    for _ in 0..2 {
        let r = compass.read().await.unwrap();
        assert!((r.heading_rad + 2.0).abs() < 1e-3, "{r:?}");
    }
}

/// `odocal heading --samples 5` on mock compasses at 0.5, 1, 10 and 50 Hz (the line ends
/// varied): five fresh readings each, the slow ones waited for at their own rate; and the noise
/// per reading of fifty.
#[test]
fn heading_reads_five_samples_from_compasses_at_any_rate() {
    for (hz, end) in [("0.5", "crlf"), ("1", "cr"), ("10", "lf"), ("50", "crlf")] {
        let (mut mock, lines) = common::spawn_server_lines(
            "mock-device",
            &[
                "--real-time",
                "1",
                // The robot's own compass quiet: the sentences carry the NMEA compass's 0.2°.
                "--compass-sigma-deg",
                "0",
                "--nmea",
                "--nmea-hz",
                hz,
                "--nmea-line-end",
                end,
            ],
            2,
        );
        let port = format!("{}?baud=115200", lines[1]);
        let v = common::odocal_json(&["heading", "--port", &port, "--samples", "5", "--json"]);
        if hz == "10" {
            // A deviation given on the command line is removed from what is read (B1 10°:
            // d(ψ) = 10°·cos ψ), as calibrate removes it.
            let corrected = common::odocal_json(&[
                "heading",
                "--port",
                &port,
                "--samples",
                "5",
                "--compass-deviation-deg",
                "0,10,0,0",
                "--json",
            ]);
            let (raw, fixed) = (
                v["heading_deg"].as_f64().unwrap(),
                corrected["heading_deg"].as_f64().unwrap(),
            );
            let removed = raw - fixed;
            let want = 10.0 * raw.to_radians().cos();
            assert!(
                (removed - want).abs() < 0.5,
                "{raw}° → {fixed}°: {removed} vs {want}"
            );
        }
        if hz == "50" {
            // Fifty readings at rest give the noise per reading `odocal plan` wants: the
            // mock's 0.2°, within three of the estimate's standard errors (10 %).
            let many =
                common::odocal_json(&["heading", "--port", &port, "--samples", "50", "--json"]);
            let sigma = many["sigma_deg"].as_f64().unwrap_or(f64::NAN);
            assert!((0.14..=0.26).contains(&sigma), "{many}");
        }
        drop(mock.stdin.take());
        let _ = mock.wait();
        assert_eq!(v["samples"], 5, "{hz} Hz: {v}");
        assert!(
            v["heading_rad"].as_f64().is_some_and(f64::is_finite),
            "{hz} Hz: {v}"
        );
    }
}
