//! A flag several mock servers share (a leaf: it uses no other file of the binary): a mock's
//! extra NMEA compass.

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
