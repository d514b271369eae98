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

/// A token cancelled by Ctrl-C, which also prints `note` (what odocal does about it) when
/// given.
pub fn ctrl_c_token(note: Option<&'static str>) -> CancellationToken {
    let token = CancellationToken::new();
    let t = token.clone();
    tokio::spawn(async move {
        if tokio::signal::ctrl_c().await.is_ok() {
            if let Some(note) = note {
                eprintln!("\nCtrl-C: {note}");
            }
            t.cancel();
        }
    });
    token
}
