//! The terminal's questions and Ctrl-C: every prompt of the command line is asked here, on
//! stderr, and answered on stdin, so that stdout stays the command's output.

use std::io::{BufRead, Write};
use tokio_util::sync::CancellationToken;

/// Asks `question` and returns the answer's line, trimmed (empty when stdin is closed).
/// Blocking: call it off the async runtime's workers ([`tokio::task::block_in_place`]).
pub fn answer(question: &str) -> std::io::Result<String> {
    eprint!("{question} ");
    std::io::stderr().flush()?;
    let mut line = String::new();
    std::io::stdin().lock().read_line(&mut line)?;
    Ok(line.trim().to_string())
}

/// Asks a yes/no `question` (`[y/N]` is added); only an explicit yes is yes.
pub fn yes(question: &str) -> bool {
    answer(&format!("{question} [y/N]"))
        .is_ok_and(|a| matches!(a.as_str(), "y" | "Y" | "yes" | "YES"))
}

/// What stops the robot at once when odocal must leave before its own stop and restore are
/// done (a second signal, or the deadline): each base's [`odocal::base::Drive::emergency_stop`].
type Stop = Box<dyn Fn() + Send>;
static FORCED_EXIT_STOPS: std::sync::Mutex<Vec<Stop>> = std::sync::Mutex::new(Vec::new());

/// Registers `stop` (a drive's emergency stop) to be called before a forced exit.
pub fn stop_on_forced_exit(stop: impl Fn() + Send + 'static) {
    FORCED_EXIT_STOPS
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .push(Box::new(stop));
}

/// How long the stop and restore a signal starts may take before odocal leaves anyway: a
/// restore on a device that stopped answering waits out its retries.
const DEADLINE: std::time::Duration = std::time::Duration::from_secs(30);

/// A token cancelled by Ctrl-C, and on Unix by SIGTERM and SIGHUP as well (what a service
/// manager, `timeout`, `docker stop`, a closed SSH session or terminal send): each is handled
/// as Ctrl-C is, so the robot is stopped and the parameters restored. Prints `note` (what
/// odocal does about it) when given. A second signal while that is under way (a device that
/// no longer answers can hold a restore for its timeouts), or [`DEADLINE`] without an end,
/// stops the robot at once ([`stop_on_forced_exit`]) and leaves, exit status 130, saying what
/// may be left to do.
pub fn ctrl_c_token(note: Option<&'static str>) -> CancellationToken {
    let token = CancellationToken::new();
    let t = token.clone();
    // Listening before this returns: a signal right after is handled, not fatal.
    let mut signals = Signals::listen();
    tokio::spawn(async move {
        if let Some(name) = signals.recv().await {
            if let Some(note) = note {
                eprintln!("\n{name}: {note}");
            }
            t.cancel();
            // A second signal, or the deadline (the only end when no signal can be waited for).
            let again = tokio::time::timeout(DEADLINE, async {
                match signals.recv().await {
                    Some(again) => again,
                    None => std::future::pending().await,
                }
            })
            .await;
            let why = match again {
                Ok(again) => format!("{again} again"),
                Err(_) => format!("no end {} after {name}", odocal::io::seconds(&DEADLINE)),
            };
            for stop in FORCED_EXIT_STOPS
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .iter()
            {
                stop();
            }
            // Time for the link to put the stop on the wire (a drive's emergency stop queues
            // it, it does not wait for an answer that may never come).
            tokio::time::sleep(std::time::Duration::from_millis(200)).await;
            // A parameter write under way (`track --write-back`) ends first: backed up and read
            // back, or undone; never cut in half. Its own timeouts bound it; so does this.
            let writing_since = std::time::Instant::now();
            if WRITING.load(std::sync::atomic::Ordering::SeqCst) {
                eprintln!("\n{why}: the write under way finishes first (backed up and read back, or undone)");
            }
            while WRITING.load(std::sync::atomic::Ordering::SeqCst)
                && writing_since.elapsed() < DEADLINE
            {
                tokio::time::sleep(std::time::Duration::from_millis(20)).await;
            }
            eprintln!(
                "\n{why}: the robot was told to stop, leaving now. A restore cut short may have \
                 left the new parameters in place: check with `odocal params get` (or the \
                 file), and put a backup back with `odocal restore BACKUP`"
            );
            std::process::exit(130);
        }
    });
    token
}

pub use odocal::io::signals::{signal, Signals};

/// Whether a store is being written now ([`writing`]).
static WRITING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
/// A signal that came while a store was being written, held until the write ended.
static DEFERRED: std::sync::Mutex<Option<&'static str>> = std::sync::Mutex::new(None);

/// For a command that writes a store (`restore`, `export`, `params set|save|restore`): Ctrl-C,
/// SIGTERM and SIGHUP leave at once (status 130) while nothing is being written, and wait for
/// a write under way (backup, write, read-back, rollback: [`writing`]) to end, so a store is
/// never left half-written by a signal; the command then ends with status 130
/// ([`deferred_signal`]).
pub fn guard_writes() {
    let mut signals = Signals::listen();
    tokio::spawn(async move {
        while let Some(name) = signals.recv().await {
            if WRITING.load(std::sync::atomic::Ordering::SeqCst) {
                eprintln!(
                    "\n{name}: the write under way finishes first (it is backed up and read \
                     back, or rolled back), then odocal leaves"
                );
                *DEFERRED.lock().unwrap_or_else(|p| p.into_inner()) = Some(name);
            } else {
                eprintln!("\n{name}: nothing was written; leaving");
                std::process::exit(130);
            }
        }
    });
}

/// Runs `write` (a store's whole transaction) with signals held until it ends ([`guard_writes`]).
#[cfg(feature = "ros")]
pub async fn writing<T>(write: impl std::future::Future<Output = T>) -> T {
    WRITING.store(true, std::sync::atomic::Ordering::SeqCst);
    let out = write.await;
    WRITING.store(false, std::sync::atomic::Ordering::SeqCst);
    out
}

/// The signal held during a write, if one came: the command ends with status 130 after saying
/// what it did.
pub fn deferred_signal() -> Option<&'static str> {
    *DEFERRED.lock().unwrap_or_else(|p| p.into_inner())
}

/// The terminal as the write service's user ([`odocal::base::write::WriteUi`]): asks on
/// stdin (the service asks only under `WritePolicy::Ask`: `--yes` is the policy's), holds
/// signals while a write is under way ([`guard_writes`]), and shows where the backup went.
pub struct TerminalWriteUi;

impl odocal::base::write::WriteUi for TerminalWriteUi {
    fn confirm(&mut self, question: &str) -> bool {
        tokio::task::block_in_place(|| yes(question))
    }
    fn writing(&mut self, on: bool) {
        WRITING.store(on, std::sync::atomic::Ordering::SeqCst);
    }
    fn note(&mut self, line: &str) {
        eprintln!("{line}");
    }
}
