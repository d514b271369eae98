//! Calibrating a robot odocal has no backend for: implement the seam's traits for what you
//! have and hand the routine a `Base`. Here the robot keeps its parameters in a JSON file on the
//! host (a `ParamStore` of a dozen lines); its drive and compass are the in-process simulator,
//! standing in for your own `Drive` and `HeadingSource`.
//!
//! `cargo run --release --example custom_base`

use async_trait::async_trait;
use odocal::base::{Base, BaseError, ComponentInfo, ParamStore};
use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::mock::SimBase;
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::{run, Unattended};
use odocal::sim::{NoiseModel, Simulator};
use std::path::PathBuf;
use std::sync::Arc;
use tokio_util::sync::CancellationToken;

/// Parameters in a JSON file; `write` stages them in the simulated controller, `commit` saves.
struct JsonFile {
    path: PathBuf,
    controller: SimBase,
}

#[async_trait]
impl ParamStore for JsonFile {
    fn info(&self) -> ComponentInfo {
        let id = self.path.display().to_string();
        ComponentInfo {
            kind: "json-file".into(),
            id,
            details: serde_json::Value::Null,
        }
    }
    async fn read(&self) -> Result<WheelParams, BaseError> {
        ParamStore::read(&self.controller).await
    }
    async fn write(&self, p: &WheelParams) -> Result<WheelParams, BaseError> {
        ParamStore::write(&self.controller, p).await
    }
    async fn commit(&self) -> Result<(), BaseError> {
        let text = serde_json::to_string_pretty(&self.controller.configured()).map_err(io)?;
        let tmp = self.path.with_extension("tmp");
        std::fs::write(&tmp, text)
            .and_then(|()| std::fs::rename(&tmp, &self.path))
            .map_err(io)
    }
    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError> {
        let Ok(text) = std::fs::read_to_string(&self.path) else {
            return Ok(None);
        };
        serde_json::from_str(&text).map(Some).map_err(io)
    }
    fn resolution(&self) -> WheelParams {
        WheelParams::nominal(1e-12, 1e-12, 1e-9)
    }
}

fn io(e: impl std::error::Error + Send + Sync + 'static) -> BaseError {
    BaseError::backend("json-file", e)
}

#[tokio::main]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The robot: configured as nominal, truly E_b 0.976, E_d 0.992, compass σ 0.37°.
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let truth = WheelParams::from_ratios(&nominal, 0.976, 0.992, &SplitConvention::LeftNominal)?;
    let noise = NoiseModel {
        compass_sigma_rad: 0.37f64.to_radians(),
        ..NoiseModel::default()
    };
    let robot = SimBase::new(Simulator::new(truth, nominal, noise, 1)?);
    let dir = std::env::temp_dir().join("odocal-custom-base");
    std::fs::create_dir_all(&dir)?;

    // The part that is about odocal: compose a base, configure the routine, run it.
    let store = JsonFile {
        path: dir.join("robot.json"),
        controller: robot.clone(),
    };
    let base = Base::new(
        Arc::new(robot.clone()),
        Arc::new(robot.clone()),
        Arc::new(store),
    );
    let cfg = RoutineConfig {
        write_back: WritePolicy::Yes,
        confirm_motion: false,
        settle_s: 0.0,
        backup_dir: Some(dir.clone()),
        ..RoutineConfig::default()
    };
    let report = run(
        &base,
        &cfg,
        Some(&robot),
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await?;
    print!("{}", odocal::report::summary_table(&report));
    println!("committed to {}", dir.join("robot.json").display());
    Ok(())
}
