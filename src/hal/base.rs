//! The seam ([`crate::base`]) over our own protocol: a [`Client`] is a drive, a heading source
//! and a parameter store at once (`Base::single(client)`).

use super::{Client, HalError, TelemetrySample};
use crate::base::drive_backend::{
    DriveBackend, DriveOpen, DriveStatus, HeadingPart, OpenDrive, StorePart,
};
use crate::base::port_spec::PortSpec;
use crate::base::store_backend::{OpenStore, StoreBackend};
use crate::base::{
    Achieved, BaseError, ComponentInfo, Drive, HeadingKind, HeadingSample, HeadingSource,
    ParamStore, Preflight, SampleStream, TravelSample, Validity, STREAM_CAPACITY,
};
use crate::kinematics::WheelParams;
use crate::protocol::message::{
    capability, fault, heading_status, MotionAccepted, MotionMode, ParamSource,
};
use async_trait::async_trait;
use std::time::Duration;
use tokio::sync::{broadcast, mpsc};

/// The kind a controller of our protocol gives in its descriptions (and backups).
pub const KIND: &str = "odocal-protocol";

fn to_base(component: &'static str, what: &'static str) -> impl Fn(HalError) -> BaseError {
    move |e| match e {
        HalError::Nack { nack, .. } => BaseError::Refused {
            component: component.into(),
            what: what.into(),
            reason: format!("{} (field {})", nack.code, nack.detail),
        },
        HalError::InvalidArgument(reason) => BaseError::InvalidArgument {
            component: component.into(),
            reason,
        },
        HalError::WatchdogTripped => BaseError::WatchdogTripped,
        HalError::MotionTimeout { after, .. } => BaseError::MotionTimeout { after },
        other => BaseError::backend(component, other),
    }
}

impl Client {
    fn component_info(&self) -> ComponentInfo {
        let d = self.device_info();
        ComponentInfo {
            kind: KIND.into(),
            id: format!("{}-{:x}", d.firmware_id, d.serial_number),
            details: serde_json::json!({
                "port": self.label(),
                "device": d,
            }),
        }
    }

    /// The device's clock: telemetry and heading readings carry its time.
    fn clock_name(&self) -> String {
        format!("{KIND}:{}", self.component_info().id)
    }

    /// Notes the completed-motion count, starts the motion and waits until the device reports
    /// it finished, allowing for slower-than-commanded execution.
    async fn run_motion(
        &self,
        what: &'static str,
        start: impl std::future::Future<Output = Result<MotionAccepted, HalError>>,
        expected_s: f64,
    ) -> Result<(), BaseError> {
        let map = to_base("drive", what);
        let completed = self.status().await.map_err(&map)?.completed_motions;
        let mut done = self.subscribe_motion_done();
        let accepted = start.await.map_err(&map)?;
        self.wait_motion(
            accepted.motion_id,
            completed.wrapping_add(1),
            motion_limit(expected_s),
            &mut done,
        )
        .await
        .map_err(&map)
    }

    /// Starts telemetry (idempotent) and forwards each sample converted by `map` until the
    /// receiver is dropped or the link closes.
    async fn forward<T: Send + 'static>(
        &self,
        period: Duration,
        map: impl FnMut(&TelemetrySample) -> Option<T> + Send + 'static,
    ) -> Result<SampleStream<T>, HalError> {
        let mut events = self.subscribe();
        // At least 1 ms: 0 would turn telemetry off.
        self.configure_telemetry(Some(period.max(Duration::from_millis(1))))
            .await?;
        let (tx, rx) = mpsc::channel(STREAM_CAPACITY);
        let mut map = map;
        tokio::spawn(async move {
            loop {
                match events.recv().await {
                    Ok(s) => {
                        if let Some(v) = map(&s) {
                            if tx.try_send(v).is_err() && tx.is_closed() {
                                return;
                            }
                        }
                    }
                    // Lost samples are counted by the link (telemetry_dropped).
                    Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => return,
                }
            }
        });
        Ok(rx)
    }
}

#[async_trait]
impl Drive for Client {
    fn info(&self) -> ComponentInfo {
        self.component_info()
    }

    fn rounds_to_counts(&self) -> bool {
        // The device rounds every motion's wheel targets to whole counts (SPEC.md §7.6).
        true
    }

    async fn preflight(&self) -> Result<Preflight, BaseError> {
        let map = to_base("drive", "a status read");
        let status = self.status().await.map_err(&map)?;
        let mut out = Preflight::default();
        for (bit, name) in [
            (fault::MOTOR_OVERCURRENT, "motor over-current"),
            (fault::ENCODER, "encoder fault"),
            (fault::HEADING_SENSOR, "heading sensor fault"),
            (fault::WATCHDOG_TRIPPED, "watchdog tripped"),
            (fault::STORAGE, "storage fault"),
            (fault::LOW_BATTERY, "low battery"),
        ] {
            if status.fault_flags & bit != 0 {
                out.faults.push(format!("device reports {name}"));
            }
        }
        let unknown = status.fault_flags & !0x3F;
        if unknown != 0 {
            out.faults
                .push(format!("device reports fault bits {unknown:#06x}"));
        }
        self.read_encoders()
            .await
            .map_err(to_base("drive", "an encoder read"))?;
        if self.device_info().capabilities & capability::WATCHDOG == 0 {
            out.warnings.push(
                "the device has no watchdog: it will not stop by itself if this host vanishes"
                    .into(),
            );
        }
        if self.known_geometry().is_none() {
            self.get_params(ParamSource::Active)
                .await
                .map_err(to_base("drive", "a parameter read"))?;
        }
        Ok(out)
    }

    async fn arm_watchdog(&self, timeout: Duration) -> Result<Option<Duration>, BaseError> {
        if self.device_info().capabilities & capability::WATCHDOG == 0 {
            return Ok(None);
        }
        self.configure_watchdog(Some(timeout))
            .await
            .map(Some)
            .map_err(to_base("drive", "the watchdog setting"))
    }

    async fn move_straight(
        &self,
        distance_m: f64,
        max_speed_m_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        let start = Client::move_straight(self, distance_m, max_speed_m_s, MotionMode::Queue);
        self.run_motion("a straight motion", start, distance_m.abs() / max_speed_m_s)
            .await?;
        // The firmware drives each wheel to its count target (SPEC.md): executed as commanded.
        Ok(None)
    }

    async fn turn_in_place(
        &self,
        angle_rad: f64,
        max_rate_rad_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        let start = Client::turn_in_place(self, angle_rad, max_rate_rad_s, MotionMode::Queue);
        self.run_motion("a turn", start, angle_rad.abs() / max_rate_rad_s)
            .await?;
        Ok(None)
    }

    async fn stop(&self) -> Result<(), BaseError> {
        Client::stop(self).await.map_err(to_base("drive", "STOP"))
    }

    fn emergency_stop(&self) {
        Client::emergency_stop(self);
    }

    async fn travel(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<TravelSample>>, BaseError> {
        if self.device_info().capabilities & capability::TELEMETRY == 0 {
            return Ok(None);
        }
        if self.known_geometry().is_none() {
            self.get_params(ParamSource::Active)
                .await
                .map_err(to_base("drive", "a parameter read"))?;
        }
        let geometry = self.geometry.clone();
        let mut last: Option<(i64, i64)> = None;
        self.forward(period, move |s| {
            let g = (*geometry.lock().unwrap_or_else(|p| p.into_inner()))?;
            let prev = last.replace((s.left_counts, s.right_counts));
            let (l0, r0) = prev.unwrap_or((s.left_counts, s.right_counts));
            Some(TravelSample {
                time_s: s.device_time_s,
                left_m: (s.left_counts - l0) as f64 * g.left_m_per_count(),
                right_m: (s.right_counts - r0) as f64 * g.right_m_per_count(),
            })
        })
        .await
        .map(Some)
        .map_err(to_base("drive", "the telemetry setting"))
    }

    fn clock(&self) -> Option<String> {
        Some(self.clock_name())
    }

    fn diagnostics(&self) -> serde_json::Value {
        let mut v = serde_json::to_value(self.stats()).unwrap_or_default();
        if let (Some(map), Some(last)) = (v.as_object_mut(), self.last_request()) {
            map.insert("last_request".into(), format!("{last:?}").into());
        }
        v
    }
}

/// The drive of a controller that speaks odocal's protocol: `PORT` or
/// `odocal:PORT[?baud=115200]`; its compass is the heading source, its memory the store.
pub const DRIVE_BACKEND: DriveBackend = DriveBackend {
    name: "odocal",
    what: "an odocal-protocol controller",
    form: "PORT or odocal:PORT[?baud=115200]",
    options: &["baud"],
    recognise: |text| PortSpec::parse(text, "odocal", &["baud"]),
    bare_port: true,
    heading: HeadingPart::Own,
    store: StorePart::Own,
    settings: None,
    check: |spec| baud_of(spec).map(drop),
    ready: |_| Ok(()),
    place: |spec| spec.port.clone(),
    open: |how: DriveOpen| -> OpenDrive {
        Box::pin(async move {
            let (port, baud) = (how.target.spec.port.clone(), baud_of(&how.target.spec)?);
            let (client, _) = super::open_port(&port, baud).await?;
            // A device that resets or is re-plugged mid-run is reopened to restore the backup.
            let reconnect = reconnect_port(client.clone(), port, baud);
            Ok(crate::base::Base::single(client).with_reconnect(reconnect))
        })
    },
    status: Some(|target| {
        Box::pin(async move {
            let baud = baud_of(&target.spec)?;
            let (client, _) = super::open_port(&target.spec.port, baud).await?;
            let report = client.device_status().await?;
            Ok(DriveStatus {
                text: report.to_string(),
                json: report.json(),
            })
        })
    }),
};

/// A controller of odocal's protocol as a store on its own (its memory and storage), as
/// `odocal restore --to PORT` names it.
pub const STORE_BACKEND: StoreBackend = StoreBackend {
    kind: KIND,
    what: "an odocal-protocol controller",
    scheme: "odocal",
    form: "PORT or odocal:PORT[?baud=115200]",
    options: &["baud"],
    bare_port: true,
    complete: |spec| {
        spec.or_option("baud", super::DEFAULT_BAUD);
        baud_of(spec).map(drop)
    },
    of_backup: |backup, _| {
        StoreBackend::detail(backup, "port")
            .map(PortSpec::bare)
            .ok_or("which port the controller was on")
    },
    show: |spec| match baud_of(spec) {
        Ok(super::DEFAULT_BAUD) => spec.port.clone(),
        _ => spec.text("odocal"),
    },
    open: |spec: PortSpec| -> OpenStore {
        Box::pin(async move {
            let baud = baud_of(&spec)?;
            Ok(
                std::sync::Arc::new(super::open_port(&spec.port, baud).await?.0)
                    as std::sync::Arc<dyn ParamStore>,
            )
        })
    },
};

/// The `baud` option (odocal's default unless given).
pub fn baud_of(spec: &PortSpec) -> Result<u32, String> {
    spec.option("baud", super::DEFAULT_BAUD)
}

/// A [`crate::base::Reconnect`] for a device on a serial port: closes `old`'s link (a port
/// held open by a link whose device stopped answering cannot be reopened) and opens `path`
/// again at `baud`, with the handshake. For a device that reset or was re-plugged mid-run.
pub fn reconnect_port(old: Client, path: String, baud: u32) -> crate::base::Reconnect {
    std::sync::Arc::new(move || {
        let (old, path) = (old.clone(), path.clone());
        Box::pin(async move {
            old.close().await;
            let (client, _) = super::open_port(&path, baud)
                .await
                .map_err(|e| BaseError::backend("store", e))?;
            Ok(std::sync::Arc::new(client) as std::sync::Arc<dyn ParamStore>)
        })
    })
}

/// Real hardware ramps and the mock may run slower than real time: allow 3× + 2 s.
fn motion_limit(expected_s: f64) -> Duration {
    let s = 3.0 * expected_s + 2.0;
    Duration::from_secs_f64(if s.is_finite() { s.min(86_400.0) } else { 2.0 })
}

/// How long a heading sensor that answers "not new" is waited for (a sensor of 1 Hz or more).
const NEW_HEADING_WITHIN: Duration = Duration::from_millis(1500);

/// How often it is asked meanwhile.
const NEW_HEADING_POLL: Duration = Duration::from_millis(5);

#[async_trait]
impl HeadingSource for Client {
    fn info(&self) -> ComponentInfo {
        self.component_info()
    }

    /// What the device says its sensor is (HELLO capability bits 6 and 7).
    fn kind(&self) -> HeadingKind {
        use crate::protocol::message::capability;
        let caps = self.device_info().capabilities;
        match (
            caps & capability::HEADING_MAGNETIC != 0,
            caps & capability::HEADING_GYRO != 0,
        ) {
            (true, false) => HeadingKind::Magnetic,
            (false, true) => HeadingKind::Gyro,
            // Neither said, or both (a contradiction): not known.
            _ => HeadingKind::Unknown,
        }
    }

    async fn read(&self) -> Result<HeadingSample, BaseError> {
        // A device whose sensor has taken no reading since its last answer says so (SPEC.md
        // §5, READ_HEADING bit 3): read again until it has, so that readings at rest are
        // distinct samples.
        let asked = tokio::time::Instant::now();
        loop {
            let h = self
                .read_heading()
                .await
                .map_err(to_base("heading", "a heading read"))?;
            let repeated = h.sensor_status & heading_status::NOT_NEW != 0;
            if repeated && asked.elapsed() < NEW_HEADING_WITHIN {
                tokio::time::sleep(NEW_HEADING_POLL).await;
                continue;
            }
            let validity = if repeated {
                Validity::Invalid(format!(
                    "the device's heading sensor took no new reading within {}",
                    crate::io::seconds(&NEW_HEADING_WITHIN)
                ))
            } else if h.valid {
                Validity::Valid
            } else {
                Validity::Invalid(format!("sensor status {:#04x}", h.sensor_status))
            };
            return Ok(HeadingSample {
                time_s: crate::protocol::units::us_to_s(u64::from(h.timestamp_us)),
                heading_rad: h.heading_rad,
                validity,
            });
        }
    }

    async fn stream(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<HeadingSample>>, BaseError> {
        if self.device_info().capabilities & capability::TELEMETRY == 0 {
            return Ok(None);
        }
        self.forward(period, |s| Some(s.heading_sample()))
            .await
            .map(Some)
            .map_err(to_base("heading", "the telemetry setting"))
    }

    fn clock(&self) -> Option<String> {
        Some(self.clock_name())
    }
}

#[async_trait]
impl ParamStore for Client {
    fn info(&self) -> ComponentInfo {
        self.component_info()
    }

    async fn read(&self) -> Result<WheelParams, BaseError> {
        self.get_params(ParamSource::Active)
            .await
            .map_err(to_base("store", "a parameter read"))
    }

    async fn write(&self, params: &WheelParams) -> Result<WheelParams, BaseError> {
        self.set_params(params)
            .await
            .map_err(to_base("store", "the parameters"))
    }

    /// A value the wire cannot carry (SPEC.md §5 ParamsBlock) is refused before anything is
    /// backed up or sent.
    async fn check_write(&self, params: &WheelParams) -> Result<(), BaseError> {
        crate::hal::wire_params(params)
            .map(|_| ())
            .map_err(|e| BaseError::InvalidArgument {
                component: "store".into(),
                reason: e.to_string(),
            })
    }

    async fn commit(&self) -> Result<(), BaseError> {
        self.save_params()
            .await
            .map(|_| ())
            .map_err(to_base("store", "SAVE_PARAMS"))
    }

    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError> {
        match self.get_params(ParamSource::Stored).await {
            Ok(p) => Ok(Some(p)),
            // A device with nothing stored refuses the read (SPEC.md §5 GET_PARAMS).
            Err(HalError::Nack { nack, .. })
                if nack.code == crate::protocol::message::NackCode::InvalidState =>
            {
                Ok(None)
            }
            Err(e) => Err(to_base("store", "a stored-parameter read")(e)),
        }
    }

    fn resolution(&self) -> WheelParams {
        // SPEC.md §4.1: nanometres and millionths of a count.
        WheelParams {
            left_wheel_diameter_m: 1e-9,
            right_wheel_diameter_m: 1e-9,
            wheelbase_m: 1e-9,
            counts_per_wheel_rev: 1e-6,
        }
    }
}
