//! The device kit ([`crate::protocol::device`]) as it comes, on a pseudo-terminal: a kit
//! device over its ideal board ([`IdealBoard`]: perfect motors, no noise) in scaled real time.
//! It is not the mock device: no simulator, no fault injection, bytes fed to the kit's own
//! receiver as a firmware's main loop would. `odocal conformance` runs against it in the tests.

use super::pty::{spawn_on_pty, PtyServer};
use crate::protocol::device::{
    Device, DeviceConfig, IdealBoard, ParamStorage, RamStorage, SimulatedBoard, Sink,
};
use crate::protocol::frame::{Frame, MAX_FRAME};
use crate::protocol::message::{FirmwareId, ParamsBlock};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

/// A kit device over the ideal board, shared between its server and observers.
pub type SharedKit = Arc<Mutex<Device<IdealBoard, RamStorage>>>;

/// How often the server polls the device between received bytes (wall clock).
const POLL: Duration = Duration::from_millis(1);

/// The kit device of a robot of exactly `robot`'s geometry (also its factory parameters),
/// limits 1 m/s and 4 rad/s, for a host whose clock runs `time_scale` times slower than the
/// device's (its watchdog timeouts stretch by it).
pub fn kit(
    robot: ParamsBlock,
    time_scale: f64,
) -> Result<Device<IdealBoard, RamStorage>, super::MockError> {
    let board = IdealBoard::new(&robot).with_host_time_scale(time_scale);
    Ok(Device::new(
        board,
        RamStorage::default(),
        kit_config(robot),
    )?)
}

/// What the kit device reports at HELLO (`odocal-kit`, limits 1 m/s and 4 rad/s), with
/// `robot` as its factory parameters.
pub fn kit_config(robot: ParamsBlock) -> DeviceConfig {
    DeviceConfig {
        firmware_id: FirmwareId::new("odocal-kit").unwrap_or_else(|_| unreachable!()),
        firmware_version: 0x01_00_00,
        serial_number: 0x0DC0_0002,
        max_speed_mm_s: 1000,
        max_rate_mrad_s: 4000,
        factory: robot,
    }
}

/// The ideal robot `odocal kit-device` serves: 0.15 m wheels, a 0.39 m wheelbase, 4096 counts
/// per revolution.
pub const IDEAL_ROBOT: ParamsBlock = ParamsBlock {
    left_wheel_diameter_nm: 150_000_000,
    right_wheel_diameter_nm: 150_000_000,
    wheelbase_nm: 390_000_000,
    counts_per_wheel_rev_micro: 4_096_000_000,
};

/// [`kit`], shared for a server.
pub fn kit_device(robot: ParamsBlock, time_scale: f64) -> Result<SharedKit, super::MockError> {
    Ok(Arc::new(Mutex::new(kit(robot, time_scale)?)))
}

/// Locks a shared kit device (a panic elsewhere does not make its state unusable).
pub fn lock_kit<B, S>(device: &Arc<Mutex<Device<B, S>>>) -> MutexGuard<'_, Device<B, S>> {
    device.lock().unwrap_or_else(|e| e.into_inner())
}

/// Frames to write, collected while the device is locked.
#[derive(Default)]
struct Outbox(Vec<u8>);

impl Sink for Outbox {
    fn send(&mut self, frame: &Frame) -> bool {
        let mut buf = [0u8; MAX_FRAME];
        match frame.encode(&mut buf) {
            Ok(n) => {
                self.0.extend_from_slice(&buf[..n]);
                true
            }
            Err(_) => false,
        }
    }
}

/// Serves `device` (a kit device over any simulated board) over `stream` until the host
/// closes it: received bytes go to [`Device::receive`], and the device is polled at its
/// clock, which runs `time_scale` times faster than the wall clock (its board is moved there
/// first).
pub async fn serve_kit<B, P, S>(
    device: Arc<Mutex<Device<B, P>>>,
    stream: S,
    time_scale: f64,
) -> std::io::Result<()>
where
    B: SimulatedBoard,
    P: ParamStorage,
    S: AsyncRead + AsyncWrite + Unpin,
{
    let (mut rd, mut wr) = tokio::io::split(stream);
    let start = tokio::time::Instant::now();
    let origin_us = lock_kit(&device).board_mut().now_us();
    let clock = move || origin_us + (start.elapsed().as_secs_f64() * time_scale * 1e6) as u64;
    let mut chunk = [0u8; 1024];
    loop {
        let received = tokio::select! {
            r = rd.read(&mut chunk) => Some(r?),
            () = tokio::time::sleep(POLL) => None,
        };
        if received == Some(0) {
            return Ok(());
        }
        let mut out = Outbox::default();
        {
            let mut d = lock_kit(&device);
            if let Some(n) = received {
                // The bytes arrived since the clock was last moved: they are taken as of then,
                // so a server starved by a busy machine does not see its host as silent. The
                // kit measures its inter-byte gap on its own clock, so in sped-up time a frame
                // split across reads more than 20 ms / `time_scale` apart is dropped (the
                // host's retry gets through).
                d.receive(&chunk[..n], &mut out);
            }
            d.advance_to(clock(), &mut out);
        }
        if !out.0.is_empty() {
            wr.write_all(&out.0).await?;
            wr.flush().await?;
        }
    }
}

/// Creates a pseudo-terminal and serves `device` on it (see [`serve_kit`]).
pub fn spawn_kit_pty<B, P>(
    device: Arc<Mutex<Device<B, P>>>,
    time_scale: f64,
) -> std::io::Result<PtyServer<()>>
where
    B: SimulatedBoard + Send + 'static,
    P: ParamStorage + Send + 'static,
{
    spawn_on_pty(Box::new(move |master| {
        Box::pin(serve_kit(device.clone(), master, time_scale))
    }))
}
