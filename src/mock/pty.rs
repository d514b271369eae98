//! Serving a mock on a new pseudo-terminal, which a host opens by path like a USB serial
//! adapter: the mock serves the master side; the slave side is held open so that the terminal
//! survives hosts opening and closing it (the master fails with EIO while no host has it open,
//! and the mock serves again once one does).

use std::future::Future;
use std::pin::Pin;
use std::time::Duration;
use tokio_serial::SerialStream;

/// What serves the master side once; called again after EIO.
pub type ServeOnce<T> = Box<
    dyn for<'a> FnMut(
            &'a mut SerialStream,
        ) -> Pin<Box<dyn Future<Output = std::io::Result<T>> + Send + 'a>>
        + Send,
>;

/// A mock served on a pseudo-terminal; dropping it stops the mock.
pub struct PtyServer<T: Send + 'static> {
    /// Path of the terminal's slave side (e.g. `/dev/pts/5`).
    pub path: String,
    /// The server task; it ends when the mock ends (a fault that makes it vanish) or is
    /// aborted.
    pub task: tokio::task::JoinHandle<std::io::Result<T>>,
    _slave: SerialStream,
}

impl<T: Send + 'static> Drop for PtyServer<T> {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Creates a pseudo-terminal and runs `serve` on its master side until it ends with anything
/// but EIO (no host has the terminal open), which it waits out.
pub fn spawn_on_pty<T: Send + 'static>(mut serve: ServeOnce<T>) -> std::io::Result<PtyServer<T>> {
    use tokio_serial::SerialPort;
    let (master, slave) = SerialStream::pair().map_err(std::io::Error::other)?;
    let path = slave
        .name()
        .ok_or_else(|| std::io::Error::other("pseudo-terminal has no path"))?;
    let task = tokio::spawn(async move {
        let mut master = master;
        loop {
            match serve(&mut master).await {
                Err(e) if e.raw_os_error() == Some(5) => {
                    tokio::time::sleep(Duration::from_millis(5)).await;
                }
                other => return other,
            }
        }
    });
    Ok(PtyServer {
        path,
        task,
        _slave: slave,
    })
}
