//! The one write service (`odocal::base::write`) against stores that misbehave as real ones
//! do: a controller that corrupts the value it stores (a bad cell, a firmware that rounds
//! wrongly) while answering that it took it, one whose commit corrupts the stored copy, one
//! that stops answering halfway through the undo. Whatever happens, the store ends holding the
//! original (or the error says truthfully what it holds), and a backup exists that restores.
//! Refusals (bounds, a dry run, a declined question) leave no file behind.

mod common;

use async_trait::async_trait;
use odocal::base::transaction::{read_backup, Holds};
use odocal::base::write::{
    write_once, Bounds, Commit, Question, Undone, WriteError, WritePolicy, WriteRequest, WriteUi,
};
use odocal::base::{BaseError, ComponentInfo, ParamStore};
use odocal::kinematics::WheelParams;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// How a [`Faulty`] store misbehaves.
#[derive(Clone, Copy, Default)]
struct Faults {
    /// Each write stores the wheelbase 1 % off, yet answers with the value asked for.
    corrupt_write: bool,
    /// The commit stores the wheelbase 2 % off.
    corrupt_commit: bool,
    /// Every request after this many writes fails (the link is gone).
    gone_after_writes: Option<usize>,
    /// The first commit lands but its answer is lost (a timeout): whether it happened is
    /// unknown to the host.
    first_commit_unanswered: bool,
}

/// An in-memory controller with a copy in use and a committed copy.
struct Faulty {
    commits: AtomicUsize,
    active: Mutex<WheelParams>,
    committed: Mutex<Option<WheelParams>>,
    writes: AtomicUsize,
    faults: Faults,
}

impl Faulty {
    fn new(p: WheelParams, faults: Faults) -> Arc<Self> {
        Arc::new(Faulty {
            commits: AtomicUsize::new(0),
            active: Mutex::new(p),
            committed: Mutex::new(Some(p)),
            writes: AtomicUsize::new(0),
            faults,
        })
    }
    fn gone(&self) -> Result<(), BaseError> {
        match self.faults.gone_after_writes {
            Some(n) if self.writes.load(Ordering::SeqCst) > n => Err(BaseError::Refused {
                component: "store".into(),
                what: "the request".into(),
                reason: "no answer (the link is gone)".into(),
            }),
            _ => Ok(()),
        }
    }
    fn active(&self) -> WheelParams {
        *self.active.lock().unwrap()
    }
    fn committed(&self) -> Option<WheelParams> {
        *self.committed.lock().unwrap()
    }
}

#[async_trait]
impl ParamStore for Faulty {
    fn info(&self) -> ComponentInfo {
        ComponentInfo {
            kind: "faulty-test-store".into(),
            id: "one".into(),
            details: serde_json::Value::Null,
        }
    }
    async fn read(&self) -> Result<WheelParams, BaseError> {
        self.gone()?;
        Ok(self.active())
    }
    async fn write(&self, params: &WheelParams) -> Result<WheelParams, BaseError> {
        self.writes.fetch_add(1, Ordering::SeqCst);
        self.gone()?;
        let mut stored = *params;
        if self.faults.corrupt_write {
            stored.wheelbase_m *= 1.01;
        }
        *self.active.lock().unwrap() = stored;
        // It answers with what it was asked to store: only a read-back finds the corruption.
        Ok(*params)
    }
    async fn commit(&self) -> Result<(), BaseError> {
        self.gone()?;
        let mut stored = self.active();
        if self.faults.corrupt_commit {
            stored.wheelbase_m *= 1.02;
        }
        *self.committed.lock().unwrap() = Some(stored);
        if self.faults.first_commit_unanswered && self.commits.fetch_add(1, Ordering::SeqCst) == 0 {
            return Err(BaseError::MotionTimeout {
                after: std::time::Duration::from_secs(1),
            });
        }
        Ok(())
    }
    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError> {
        self.gone()?;
        Ok(self.committed())
    }
    fn resolution(&self) -> WheelParams {
        WheelParams {
            left_wheel_diameter_m: 1e-9,
            right_wheel_diameter_m: 1e-9,
            wheelbase_m: 1e-9,
            counts_per_wheel_rev: 1e-6,
        }
    }
}

fn original() -> WheelParams {
    common::nominal()
}

fn changed() -> WheelParams {
    WheelParams {
        wheelbase_m: original().wheelbase_m * 1.03,
        ..original()
    }
}

fn request(dir: &std::path::Path, commit: Commit, policy: WritePolicy) -> WriteRequest<'_> {
    WriteRequest {
        new: changed(),
        bounds: Bounds::MaxChange {
            fraction: 0.1,
            wider: None,
        },
        policy,
        commit,
        backup_dir: dir,
        question: Question::OldToNew("write these?".into()),
    }
}

/// Says `answer` and remembers what it was asked and told.
struct Ui {
    answer: bool,
    asked: Vec<String>,
    writing: Vec<bool>,
}

impl Ui {
    fn new(answer: bool) -> Self {
        Ui {
            answer,
            asked: Vec::new(),
            writing: Vec::new(),
        }
    }
}

impl WriteUi for Ui {
    fn confirm(&mut self, question: &str) -> bool {
        self.asked.push(question.into());
        self.answer
    }
    fn writing(&mut self, on: bool) {
        self.writing.push(on);
    }
}

fn files(dir: &std::path::Path) -> usize {
    std::fs::read_dir(dir).map_or(0, |r| r.count())
}

#[tokio::test]
async fn a_store_that_corrupts_a_write_is_caught_by_the_read_back_and_put_back() {
    let dir = common::scratch("write-corrupt");
    let store = Faulty::new(
        original(),
        Faults {
            corrupt_write: true,
            ..Faults::default()
        },
    );
    let mut ui = Ui::new(true);
    let err = write_once(
        store.clone(),
        None,
        request(&dir, Commit::Both, WritePolicy::Ask),
        &mut ui,
    )
    .await
    .unwrap_err();
    let WriteError::Failed {
        source,
        undone,
        backup,
    } = &err
    else {
        panic!("expected a failed write, got {err}");
    };
    assert!(
        matches!(source, BaseError::ReadBack { copy: "in use", .. }),
        "{source}"
    );
    // The undo's own write is corrupted too: its read-back finds it, and the statement says
    // what the store holds (neither the original nor the new parameters) and the way back.
    match &**undone {
        Undone::Failed {
            active, committed, ..
        } => {
            assert!(matches!(active, Holds::Other(_)), "{active}");
            assert_eq!(*committed, Holds::Original, "nothing was committed");
        }
        other => panic!("expected the undo found wanting, got {other}"),
    }
    let text = err.to_string();
    assert!(text.contains("in use other parameters"), "{text}");
    assert!(
        text.contains(&format!("odocal restore {}", backup.display())),
        "{text}"
    );
    assert_eq!(store.committed(), Some(original()));
    // The question showed old → new, and signals were held from the backup to the undo.
    assert_eq!(ui.asked.len(), 1);
    assert!(ui.asked[0].contains("wheelbase (m)"), "{}", ui.asked[0]);
    assert_eq!(ui.writing, [true, false]);
    // The backup holds the original and is one `odocal restore` takes.
    assert_eq!(read_backup(backup).unwrap().active, original());
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test]
async fn a_commit_that_corrupts_the_stored_copy_is_undone_in_both_copies() {
    let dir = common::scratch("write-corrupt-commit");
    let store = Faulty::new(
        original(),
        Faults {
            corrupt_commit: true,
            ..Faults::default()
        },
    );
    let err = write_once(
        store.clone(),
        None,
        request(&dir, Commit::Both, WritePolicy::Yes),
        &mut Ui::new(false),
    )
    .await
    .unwrap_err();
    match &err {
        WriteError::Failed { source, undone, .. } => {
            assert!(
                matches!(
                    source,
                    BaseError::ReadBack {
                        copy: "committed",
                        ..
                    }
                ),
                "{source}"
            );
            // The copy in use is the original again; the undo's commit is corrupted as well,
            // and the statement says so rather than "restored".
            match &**undone {
                Undone::Failed {
                    active, committed, ..
                } => {
                    assert_eq!(*active, Holds::Original);
                    assert!(matches!(committed, Holds::Other(_)), "{committed}");
                }
                other => panic!("expected the undo found wanting, got {other}"),
            }
        }
        other => panic!("expected a failed write, got {other}"),
    }
    assert_eq!(store.active(), original());
    let committed = store.committed().unwrap();
    assert!((committed.wheelbase_m / original().wheelbase_m - 1.02).abs() < 1e-9);
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test]
async fn a_store_gone_during_the_undo_is_reported_with_what_it_holds_and_the_way_back() {
    let dir = common::scratch("write-gone");
    // The first write lands corrupted; the undo's write finds the link gone.
    let store = Faulty::new(
        original(),
        Faults {
            corrupt_write: true,
            gone_after_writes: Some(1),
            ..Faults::default()
        },
    );
    let err = write_once(
        store.clone(),
        None,
        request(&dir, Commit::InUse, WritePolicy::Yes),
        &mut Ui::new(true),
    )
    .await
    .unwrap_err();
    let WriteError::Failed { undone, backup, .. } = &err else {
        panic!("expected a failed write, got {err}");
    };
    match &**undone {
        Undone::Failed {
            active, committed, ..
        } => {
            // Nothing answers: nothing is claimed.
            assert!(matches!(active, Holds::Unknown(_)), "{active}");
            assert!(matches!(committed, Holds::Unknown(_)), "{committed}");
        }
        other => panic!("expected a failed undo, got {other}"),
    }
    let text = err.to_string();
    assert!(
        text.contains(&format!("odocal restore {}", backup.display())),
        "{text}"
    );
    assert_ne!(
        store.active(),
        original(),
        "the corrupted write is still there"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test]
async fn refusals_write_nothing_and_leave_no_file() {
    let dir = common::scratch("write-refused");
    let store = Faulty::new(original(), Faults::default());
    // Beyond the bounds: refused before anything is asked.
    let mut far = request(&dir, Commit::Both, WritePolicy::Ask);
    far.new.wheelbase_m = original().wheelbase_m * 1.5;
    let mut ui = Ui::new(true);
    let err = write_once(store.clone(), None, far, &mut ui)
        .await
        .unwrap_err();
    assert!(matches!(err, WriteError::OutOfBounds(_)), "{err}");
    assert!(ui.asked.is_empty());
    // A dry run and a declined question: every check made, nothing written.
    for (policy, answer) in [(WritePolicy::DryRun, true), (WritePolicy::Ask, false)] {
        let err = write_once(
            store.clone(),
            None,
            request(&dir, Commit::Both, policy),
            &mut Ui::new(answer),
        )
        .await
        .unwrap_err();
        assert!(
            matches!(err, WriteError::DryRun | WriteError::Declined(_)),
            "{err}"
        );
    }
    assert_eq!(files(&dir), 0, "no backup for a write that never happened");
    assert_eq!(store.active(), original());
    assert_eq!(store.writes.load(Ordering::SeqCst), 0);
    // And a write that goes through: backed up, written, committed, read back.
    let done = write_once(
        store.clone(),
        None,
        request(&dir, Commit::Both, WritePolicy::Yes),
        &mut Ui::new(false),
    )
    .await
    .unwrap();
    assert_eq!(done.before, original());
    assert_eq!(done.applied, changed());
    assert_eq!(store.committed(), Some(changed()));
    assert_eq!(read_backup(&done.backup).unwrap().active, original());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `params save` of parameters never committed: the stored copy differs from the one in use.
/// A save whose answer is lost may have landed, so it is undone, and undoing it puts the
/// stored copy the backup holds back (not the copy in use, which is what was being saved).
#[tokio::test]
async fn an_unanswered_save_is_undone_to_the_stored_copy_the_backup_holds() {
    let dir = common::scratch("write-save");
    let store = Faulty::new(
        original(),
        Faults {
            first_commit_unanswered: true,
            ..Faults::default()
        },
    );
    // In use: changed (set, never saved); stored: the original.
    *store.active.lock().unwrap() = changed();
    let save = WriteRequest {
        new: changed(),
        bounds: Bounds::Physical,
        policy: WritePolicy::Yes,
        commit: Commit::Both,
        backup_dir: &dir,
        question: Question::Plain(String::new()),
    };
    let err = write_once(store.clone(), None, save, &mut Ui::new(true))
        .await
        .unwrap_err();
    match &err {
        WriteError::Failed { undone, .. } => assert!(
            matches!(
                **undone,
                Undone::Restored {
                    committed: true,
                    ..
                }
            ),
            "{undone}"
        ),
        other => panic!("expected a failed save, got {other}"),
    }
    assert_eq!(
        store.committed(),
        Some(original()),
        "the stored copy is back"
    );
    assert_eq!(store.active(), changed(), "what was in use is in use");
    let _ = std::fs::remove_dir_all(&dir);
}
