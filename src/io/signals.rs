//! The signals that end a session the way Ctrl-C does: SIGINT, and on Unix SIGTERM and SIGHUP
//! (what a service manager, `timeout`, `docker stop`, a closed SSH session or terminal send).
//! Whoever listens handles each as Ctrl-C: the robot stopped, the parameters restored.

/// Ctrl-C, SIGTERM and SIGHUP, listened for from the moment this is made: a signal that comes
/// before the first [`Signals::recv`] is not lost, nor does it kill the process.
pub struct Signals {
    #[cfg(unix)]
    unix: Option<[tokio::signal::unix::Signal; 3]>,
}

impl Signals {
    /// Starts listening (on Unix the handlers are installed now, before this returns).
    pub fn listen() -> Self {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{signal, SignalKind};
            let unix = match (
                signal(SignalKind::interrupt()),
                signal(SignalKind::terminate()),
                signal(SignalKind::hangup()),
            ) {
                (Ok(int), Ok(term), Ok(hup)) => Some([int, term, hup]),
                _ => None,
            };
            Signals { unix }
        }
        #[cfg(not(unix))]
        Signals {}
    }

    /// The next signal's name, or `None` when no signal can be waited for.
    pub async fn recv(&mut self) -> Option<&'static str> {
        #[cfg(unix)]
        if let Some([int, term, hup]) = self.unix.as_mut() {
            return tokio::select! {
                r = int.recv() => r.map(|()| "Ctrl-C"),
                r = term.recv() => r.map(|()| "SIGTERM"),
                r = hup.recv() => r.map(|()| "SIGHUP"),
            };
        }
        tokio::signal::ctrl_c().await.ok().map(|()| "Ctrl-C")
    }
}

/// Waits for the first of Ctrl-C, SIGTERM and SIGHUP from now on; its name, or `None` when no
/// signal can be waited for.
pub async fn signal() -> Option<&'static str> {
    Signals::listen().recv().await
}
