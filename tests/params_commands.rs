//! `odocal params` as the library does it (`hal::params`), against the mock device over an
//! in-memory duplex: set, save and the factory copy put back, each through the write service;
//! a refusal, a declined question and a device that is gone change nothing.

mod common;

use odocal::base::write::{Unattended, WriteError, WriteUi};
use odocal::hal::link::LinkConfig;
use odocal::hal::params::{self, ParamsError, ParamsPatch};
use odocal::hal::Client;
use odocal::mock::{spawn_duplex, FaultConfig, SharedDevice, TimeMode};
use odocal::protocol::message::ParamSource;
use std::sync::Arc;
use std::time::Duration;

fn link() -> LinkConfig {
    LinkConfig {
        response_time: Duration::from_millis(10),
        margin: Duration::from_millis(5),
        ..LinkConfig::default()
    }
}

async fn connected(faults: FaultConfig) -> (Arc<Client>, SharedDevice) {
    let dev = common::mock_device(0.37, 5);
    let (stream, _task) = spawn_duplex(dev.clone(), TimeMode::Virtual, faults);
    let (client, _) = Client::connect(stream, link()).await.unwrap();
    (Arc::new(client), dev)
}

/// Says no to every question.
struct Declines;

impl WriteUi for Declines {
    fn confirm(&mut self, _question: &str) -> bool {
        false
    }
}

fn backups(dir: &std::path::Path) -> usize {
    std::fs::read_dir(dir).map_or(0, |d| d.count())
}

#[tokio::test]
async fn set_save_and_factory_restore_write_what_they_say_and_back_up_first() {
    let (client, _dev) = connected(FaultConfig::default()).await;
    let dir = common::scratch("params-set-save");
    let factory = client.get_params(ParamSource::Factory).await.unwrap();
    let patch = ParamsPatch {
        wheelbase_m: Some(0.4),
        ..ParamsPatch::default()
    };
    let set = params::set(&client, &patch, &dir, &mut Unattended)
        .await
        .unwrap();
    assert_eq!(set.applied, patch.applied_to(&factory));
    assert_eq!(
        client.get_params(ParamSource::Active).await.unwrap(),
        set.applied
    );
    assert!(set.backup.exists());

    let saved = params::save(&client, &dir, &mut Unattended).await.unwrap();
    assert_eq!(
        client.get_params(ParamSource::Stored).await.unwrap(),
        saved.applied
    );
    assert_eq!(saved.applied, set.applied);

    let back = params::restore_factory(&client, (true, true), &dir, &mut Unattended).await;
    assert_eq!(back.unwrap().applied, factory);
    assert_eq!(
        client.get_params(ParamSource::Active).await.unwrap(),
        factory
    );
    assert_eq!(
        client.get_params(ParamSource::Stored).await.unwrap(),
        factory
    );
    assert_eq!(
        backups(&dir),
        3,
        "one new backup per write, none overwritten"
    );
}

#[tokio::test]
async fn a_refused_value_a_declined_question_and_a_vanished_device_change_nothing() {
    let (client, _dev) = connected(FaultConfig::default()).await;
    let dir = common::scratch("params-refusals");
    let before = client.get_params(ParamSource::Active).await.unwrap();
    let absurd = ParamsPatch {
        wheelbase_m: Some(-0.4),
        ..ParamsPatch::default()
    };
    let e = params::set(&client, &absurd, &dir, &mut Unattended)
        .await
        .unwrap_err();
    // Refused before anything is backed up: the wire cannot carry it (SPEC.md §4.1).
    assert!(matches!(e, ParamsError::Write(WriteError::Base(_))), "{e}");
    assert!(e.to_string().ends_with("(nothing was changed)"), "{e}");
    // Asked (no --yes) and declined.
    let e = params::restore_factory(&client, (false, false), &dir, &mut Declines).await;
    assert!(
        matches!(e, Err(ParamsError::Write(WriteError::Declined(_)))),
        "{e:?}"
    );
    assert_eq!(
        client.get_params(ParamSource::Active).await.unwrap(),
        before
    );
    assert_eq!(backups(&dir), 0, "nothing written, nothing backed up");

    // The device answers HELLO and then nothing: the read before any write fails, typed.
    let silent = FaultConfig {
        disconnect_after_frames: Some(1),
        ..FaultConfig::default()
    };
    let (gone, _dev) = connected(silent).await;
    let e = params::save(&gone, &dir, &mut Unattended)
        .await
        .unwrap_err();
    assert!(matches!(e, ParamsError::Read(_)), "{e}");
    assert_eq!(backups(&dir), 0);
}
