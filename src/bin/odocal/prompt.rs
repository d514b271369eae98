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

/// A token cancelled by Ctrl-C, and on Unix by SIGTERM and SIGHUP as well (what a service
/// manager, `timeout`, `docker stop`, a closed SSH session or terminal send): each is handled
/// as Ctrl-C is, so the robot is stopped and the parameters restored. Prints `note` (what
/// odocal does about it) when given. A second signal while that is under way (a device that
/// no longer answers can hold a restore for its timeouts) leaves at once, exit status 130,
/// saying what may be left to do.
pub fn ctrl_c_token(note: Option<&'static str>) -> CancellationToken {
    let token = CancellationToken::new();
    let t = token.clone();
    tokio::spawn(async move {
        if let Some(name) = signal().await {
            if let Some(note) = note {
                eprintln!("\n{name}: {note}");
            }
            t.cancel();
            if let Some(again) = signal().await {
                eprintln!(
                    "\n{again} again: leaving now. The controller's watchdog or command timeout \
                     stops the robot; a restore cut short may have left the new parameters in \
                     place: check with `odocal params get` (or the file), and put a backup back \
                     with `odocal restore BACKUP`"
                );
                std::process::exit(130);
            }
        }
    });
    token
}

/// Waits for the first of Ctrl-C, SIGTERM and SIGHUP; its name, or `None` when no signal can
/// be waited for.
async fn signal() -> Option<&'static str> {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        if let (Ok(mut term), Ok(mut hup)) = (
            signal(SignalKind::terminate()),
            signal(SignalKind::hangup()),
        ) {
            return tokio::select! {
                r = tokio::signal::ctrl_c() => r.ok().map(|()| "Ctrl-C"),
                _ = term.recv() => Some("SIGTERM"),
                _ = hup.recv() => Some("SIGHUP"),
            };
        }
    }
    tokio::signal::ctrl_c().await.ok().map(|()| "Ctrl-C")
}
