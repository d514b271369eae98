//! Flags several commands share (a leaf: it uses no other file of the binary): a mock's extra
//! NMEA compass and how a mock server is stopped.

/// A mock NMEA compass on the simulated robot of a mock server (`--nmea`): its terminal is
/// printed as `nmea:PATH` on the line after the server's own.
#[derive(Debug, Clone, clap::Args)]
pub struct MockCompassArgs {
    #[command(flatten)]
    compass: odocal::mock::options::ExtraCompass,
}

impl MockCompassArgs {
    /// Starts the compass if asked for and prints its spec; keep the handle while serving.
    pub fn spawn(
        &self,
        heading: odocal::mock::nmea::HeadingFn,
        time_scale: f64,
    ) -> Result<Option<odocal::mock::PtyServer<()>>, Box<dyn std::error::Error>> {
        let Some(cfg) = self.compass.config(time_scale)? else {
            return Ok(None);
        };
        let pty = odocal::mock::nmea::spawn_pty(cfg, heading)?;
        println!("nmea:{}", pty.path);
        Ok(Some(pty))
    }
}

/// " or closing stdin" unless a mock server ignores its stdin: how the server is stopped.
pub fn or_stdin(ignore_stdin: bool) -> &'static str {
    if ignore_stdin {
        ""
    } else {
        " or closing stdin"
    }
}

/// Waits until Ctrl-C, or until stdin closes unless `ignore_stdin` (how a test or a script
/// that started a mock server stops it).
pub async fn serve_until_stopped(ignore_stdin: bool) {
    let stdin_closed = async {
        if ignore_stdin {
            std::future::pending::<()>().await;
        }
        let mut sink = Vec::new();
        let _ = tokio::io::AsyncReadExt::read_to_end(&mut tokio::io::stdin(), &mut sink).await;
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        () = stdin_closed => {}
    }
}
