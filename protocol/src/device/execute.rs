//! A request's answer: each message of SPEC.md §5 carried out on the device, or the NACK that
//! says why not.

use super::*;

impl<B: Board, S: ParamStorage> Device<B, S> {
    pub(super) fn info(&self) -> DeviceInfo {
        let mut capabilities = capability::TELEMETRY
            | capability::WATCHDOG
            | capability::WHEEL_SPEED
            | capability::MOTION_QUEUE;
        if self.board.has_heading() {
            capabilities |= capability::HEADING
                | (self.board.heading_kind()
                    & (capability::HEADING_MAGNETIC | capability::HEADING_GYRO));
        }
        if S::NON_VOLATILE {
            capabilities |= capability::STORAGE;
        }
        DeviceInfo {
            major: MAJOR,
            minor: MINOR,
            firmware_id: self.config.firmware_id,
            firmware_version: self.config.firmware_version,
            capabilities,
            serial_number: self.config.serial_number,
            max_speed_mm_s: self.config.max_speed_mm_s,
            max_rate_mrad_s: self.config.max_rate_mrad_s,
        }
    }

    /// Executes one decoded request, checking in SPEC.md §7.5's order: fields in payload
    /// order, then state, then queue space.
    pub(super) fn execute(&mut self, request: &Request) -> Result<Response, Nack> {
        let now = self.clock();
        match *request {
            Request::Hello(hello) => self.hello(hello),
            Request::GetParams(GetParamsRequest { source }) => self.get_params(source),
            Request::SetParams(b) => {
                if let Err(field) = b.validate() {
                    return refuse(NackCode::OutOfRange, field);
                }
                self.require_idle()?;
                self.active = b;
                Ok(Response::SetParams(b))
            }
            Request::SaveParams => {
                self.require_idle()?;
                let b = self.active;
                self.save(b)?;
                Ok(Response::SaveParams(SavedCrc {
                    stored_crc: block_crc(&b),
                }))
            }
            Request::RestoreDefaults(RestoreDefaultsRequest { target }) => {
                self.restore_defaults(target)
            }
            Request::LoadParams => {
                self.require_idle()?;
                self.active = self.stored.unwrap_or(self.config.factory);
                Ok(Response::LoadParams(self.active))
            }
            Request::ResetOdometry => {
                self.require_idle()?;
                self.board.reset_encoders();
                Ok(Response::ResetOdometry)
            }
            Request::MoveStraight(m) => self.move_straight(m),
            Request::TurnInPlace(t) => self.turn_in_place(t),
            Request::WheelSpeed(w) => self.wheel_speed(w),
            Request::Stop => {
                self.stats.stop_requests += 1;
                self.stop();
                Ok(Response::Stop)
            }
            Request::GetStatus => Ok(Response::GetStatus(self.status())),
            Request::ReadEncoders => {
                let (left_counts, right_counts) = self.board.encoders();
                Ok(Response::ReadEncoders(Encoders {
                    timestamp_us: now as u32,
                    left_counts,
                    right_counts,
                }))
            }
            Request::ReadHeading => Ok(Response::ReadHeading(self.read_heading(now))),
            Request::ConfigureTelemetry(TelemetryPeriod { period_ms }) => {
                if period_ms != 0 && !(5..=1000).contains(&period_ms) {
                    return refuse(NackCode::OutOfRange, 0);
                }
                self.telemetry.configure(u64::from(period_ms) * 1000, now);
                Ok(Response::ConfigureTelemetry(TelemetryPeriod { period_ms }))
            }
            Request::ConfigureWatchdog(w) => self.configure_watchdog(w, now),
            Request::Heartbeat => {
                if self.watchdog.state() == WatchdogState::Tripped {
                    self.watchdog.acknowledge();
                    self.faults &= !fault::WATCHDOG_TRIPPED;
                }
                Ok(Response::Heartbeat)
            }
        }
    }

    fn hello(&mut self, hello: HelloRequest) -> Result<Response, Nack> {
        let HelloRequest {
            host_major,
            host_min_minor,
        } = hello;
        if host_major != MAJOR || MINOR < host_min_minor {
            // SPEC 1.1: the detail tells the host which version this device speaks.
            return refuse(NackCode::VersionMismatch, (MAJOR << 4) | MINOR);
        }
        Ok(Response::Hello(self.info()))
    }

    fn get_params(&mut self, source: ParamSource) -> Result<Response, Nack> {
        let (params, stored_crc) = match source {
            ParamSource::Active => (self.active, 0),
            ParamSource::Stored => match self.stored {
                Some(b) => (b, block_crc(&b)),
                None => return refuse(NackCode::StorageFailure, 0),
            },
            ParamSource::Factory => (self.config.factory, 0),
        };
        Ok(Response::GetParams(StoredParams {
            source,
            params,
            stored_crc,
        }))
    }

    fn restore_defaults(&mut self, target: RestoreTarget) -> Result<Response, Nack> {
        self.require_idle()?;
        let b = self.config.factory;
        // Stored first: a failed write leaves everything as it was.
        if target == RestoreTarget::ActiveAndStored {
            self.save(b)?;
        }
        self.active = b;
        Ok(Response::RestoreDefaults(b))
    }

    fn move_straight(&mut self, request: MoveStraightRequest) -> Result<Response, Nack> {
        let MoveStraightRequest {
            distance_um,
            max_speed_mm_s,
            mode,
        } = request;
        let d = distance_um.unsigned_abs();
        motion_fields(
            d,
            MAX_DISTANCE_UM,
            max_speed_mm_s,
            self.config.max_speed_mm_s,
        )?;
        let arc = units::um_to_m(distance_um);
        self.accept_counts([arc, arc], d, max_speed_mm_s, mode)
            .map(Response::MoveStraight)
    }

    fn turn_in_place(&mut self, request: TurnInPlaceRequest) -> Result<Response, Nack> {
        let TurnInPlaceRequest {
            angle_urad,
            max_rate_mrad_s,
            mode,
        } = request;
        let a = angle_urad.unsigned_abs();
        motion_fields(
            a,
            MAX_ANGLE_URAD,
            max_rate_mrad_s,
            self.config.max_rate_mrad_s,
        )?;
        // Right wheel +angle·b/2, left −angle·b/2 (SPEC.md §5).
        let half = 0.5 * units::urad_to_rad(angle_urad) * self.active.to_si().wheelbase_m;
        self.accept_counts([0.0 - half, 0.0 + half], a, max_rate_mrad_s, mode)
            .map(Response::TurnInPlace)
    }

    fn wheel_speed(&mut self, request: WheelSpeedRequest) -> Result<Response, Nack> {
        let WheelSpeedRequest {
            left_mm_s,
            right_mm_s,
            duration_ms,
        } = request;
        if left_mm_s.unsigned_abs() > self.config.max_speed_mm_s {
            return refuse(NackCode::OutOfRange, 0);
        }
        if right_mm_s.unsigned_abs() > self.config.max_speed_mm_s {
            return refuse(NackCode::OutOfRange, 1);
        }
        let speeds = [
            units::mm_s_to_m_s(i32::from(left_mm_s)),
            units::mm_s_to_m_s(i32::from(right_mm_s)),
        ];
        let travel = if duration_ms == 0 {
            // Counts per second: the targets of one second's travel, unrounded.
            let p = self.active.to_si();
            Travel::OpenEnded {
                left_counts_s: speeds[0] / (PI * p.left_wheel_diameter_m / p.counts_per_wheel_rev),
                right_counts_s: speeds[1]
                    / (PI * p.right_wheel_diameter_m / p.counts_per_wheel_rev),
            }
        } else {
            let t = f64::from(duration_ms) / 1e3;
            let [left, right] = self.counts([speeds[0] * t, speeds[1] * t]).ok_or(Nack {
                code: NackCode::OutOfRange,
                detail: 2,
            })?;
            Travel::Counts {
                left,
                right,
                duration_us: u64::from(duration_ms) * 1000,
            }
        };
        // A WHEEL_SPEED replaces the queue (SPEC.md §7.4).
        self.accept(travel, MotionMode::Replace)?;
        Ok(Response::WheelSpeed)
    }

    fn read_heading(&mut self, now: u64) -> Heading {
        let h = self.board.heading();
        // The same sample as the last answer is flagged (SPEC.md §5): the host reads again.
        // Telemetry reads the sensor too and does not count.
        let sample = self.board.heading_sample();
        let repeated = sample.is_some() && sample == self.heading_answered;
        self.heading_answered = sample;
        Heading {
            timestamp_us: now as u32,
            heading_urad: h.heading_urad,
            valid: h.valid,
            sensor_status: if repeated {
                h.sensor_status | heading_status::NOT_NEW
            } else {
                h.sensor_status
            },
        }
    }

    fn configure_watchdog(&mut self, request: WatchdogTimeout, now: u64) -> Result<Response, Nack> {
        let WatchdogTimeout { timeout_ms } = request;
        if timeout_ms != 0 && !(50..=10_000).contains(&timeout_ms) {
            return refuse(NackCode::OutOfRange, 0);
        }
        let timeout_us = if timeout_ms == 0 {
            0
        } else {
            self.board.watchdog_timeout_us(timeout_ms).max(1)
        };
        self.watchdog.configure(timeout_us, now);
        self.faults &= !fault::WATCHDOG_TRIPPED;
        Ok(Response::ConfigureWatchdog(WatchdogTimeout { timeout_ms }))
    }

    pub(super) fn save(&mut self, b: ParamsBlock) -> Result<(), Nack> {
        self.storage
            .save(&b)
            .or_else(|_| refuse(NackCode::StorageFailure, 0xFF))?;
        self.stored = Some(b);
        Ok(())
    }
}

pub(super) fn refuse<T>(code: NackCode, detail: u8) -> Result<T, Nack> {
    Err(Nack { code, detail })
}
