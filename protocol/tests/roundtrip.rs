//! Property tests: every message, with any field values, survives encode → frame bytes →
//! decode unchanged, including when the bytes arrive split at any point.
#![cfg(feature = "tokio")]

use bytes::BytesMut;
use odocal_protocol::message::*;
use odocal_protocol::FrameCodec;
use proptest::prelude::*;

fn params() -> impl Strategy<Value = ParamsBlock> {
    (any::<u32>(), any::<u32>(), any::<u32>(), any::<u64>()).prop_map(|(l, r, b, c)| ParamsBlock {
        left_wheel_diameter_nm: l,
        right_wheel_diameter_nm: r,
        wheelbase_nm: b,
        counts_per_wheel_rev_micro: c,
    })
}

fn source() -> impl Strategy<Value = ParamSource> {
    (0u8..3).prop_map(|b| ParamSource::from_byte(b).unwrap())
}
fn mode() -> impl Strategy<Value = MotionMode> {
    (0u8..2).prop_map(|b| MotionMode::from_byte(b).unwrap())
}
fn motion_state() -> impl Strategy<Value = MotionState> {
    (0u8..4).prop_map(|b| MotionState::from_byte(b).unwrap())
}

fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        (any::<u8>(), any::<u8>()).prop_map(|(a, b)| Request::Hello(HelloRequest {
            host_major: a,
            host_min_minor: b
        })),
        source().prop_map(|source| Request::GetParams(GetParamsRequest { source })),
        params().prop_map(Request::SetParams),
        Just(Request::SaveParams),
        (0u8..2).prop_map(|b| Request::RestoreDefaults(RestoreDefaultsRequest {
            target: RestoreTarget::from_byte(b).unwrap()
        })),
        Just(Request::LoadParams),
        Just(Request::ResetOdometry),
        (any::<i32>(), any::<u16>(), mode()).prop_map(|(d, s, mode)| Request::MoveStraight(
            MoveStraightRequest {
                distance_um: d,
                max_speed_mm_s: s,
                mode
            }
        )),
        (any::<i32>(), any::<u16>(), mode()).prop_map(|(a, r, mode)| Request::TurnInPlace(
            TurnInPlaceRequest {
                angle_urad: a,
                max_rate_mrad_s: r,
                mode
            }
        )),
        (any::<i16>(), any::<i16>(), any::<u16>()).prop_map(|(l, r, d)| Request::WheelSpeed(
            WheelSpeedRequest {
                left_mm_s: l,
                right_mm_s: r,
                duration_ms: d
            }
        )),
        Just(Request::Stop),
        Just(Request::GetStatus),
        Just(Request::ReadEncoders),
        Just(Request::ReadHeading),
        any::<u16>().prop_map(|p| Request::ConfigureTelemetry(TelemetryPeriod { period_ms: p })),
        any::<u16>().prop_map(|t| Request::ConfigureWatchdog(WatchdogTimeout { timeout_ms: t })),
        Just(Request::Heartbeat),
    ]
}

fn response() -> impl Strategy<Value = Response> {
    let info = (
        any::<u8>(),
        any::<u8>(),
        "[ -~]{0,16}",
        any::<u32>(),
        any::<u32>(),
        any::<u64>(),
        any::<u16>(),
        any::<u16>(),
    )
        .prop_map(
            |(major, minor, firmware_id, fv, caps, sn, ms, mr)| DeviceInfo {
                major,
                minor,
                firmware_id: FirmwareId::new(&firmware_id).unwrap(),
                firmware_version: fv,
                capabilities: caps,
                serial_number: sn,
                max_speed_mm_s: ms,
                max_rate_mrad_s: mr,
            },
        );
    let accepted = (any::<u8>(), any::<u16>()).prop_map(|(q, m)| MotionAccepted {
        queue_depth: q,
        motion_id: m,
    });
    let status = (
        motion_state(),
        any::<u8>(),
        any::<u16>(),
        any::<u32>(),
        any::<u16>(),
        (0u8..3).prop_map(|b| WatchdogState::from_byte(b).unwrap()),
        any::<u32>(),
    )
        .prop_map(|(ms, q, c, n, f, w, u)| Status {
            motion_state: ms,
            queue_depth: q,
            current_motion_id: c,
            completed_motions: n,
            fault_flags: f,
            watchdog_state: w,
            uptime_ms: u,
        });
    prop_oneof![
        info.prop_map(Response::Hello),
        (source(), params(), any::<u16>()).prop_map(|(source, params, stored_crc)| {
            Response::GetParams(StoredParams {
                source,
                params,
                stored_crc,
            })
        }),
        params().prop_map(Response::SetParams),
        any::<u16>().prop_map(|c| Response::SaveParams(SavedCrc { stored_crc: c })),
        params().prop_map(Response::RestoreDefaults),
        params().prop_map(Response::LoadParams),
        Just(Response::ResetOdometry),
        accepted.clone().prop_map(Response::MoveStraight),
        accepted.prop_map(Response::TurnInPlace),
        Just(Response::WheelSpeed),
        Just(Response::Stop),
        status.prop_map(Response::GetStatus),
        (any::<u32>(), any::<i32>(), any::<i32>()).prop_map(|(t, l, r)| Response::ReadEncoders(
            Encoders {
                timestamp_us: t,
                left_counts: l,
                right_counts: r
            }
        )),
        (any::<u32>(), any::<i32>(), any::<bool>(), any::<u8>()).prop_map(|(t, h, v, s)| {
            Response::ReadHeading(Heading {
                timestamp_us: t,
                heading_urad: h,
                valid: v,
                sensor_status: s,
            })
        }),
        any::<u16>().prop_map(|p| Response::ConfigureTelemetry(TelemetryPeriod { period_ms: p })),
        any::<u16>().prop_map(|t| Response::ConfigureWatchdog(WatchdogTimeout { timeout_ms: t })),
        Just(Response::Heartbeat),
    ]
}

fn event() -> impl Strategy<Value = Event> {
    prop_oneof![
        (
            any::<u32>(),
            any::<u32>(),
            any::<i32>(),
            any::<i32>(),
            any::<i32>(),
            any::<bool>(),
            motion_state(),
            any::<u8>()
        )
            .prop_map(|(i, t, l, r, h, v, m, q)| Event::Telemetry(Telemetry {
                sample_index: i,
                timestamp_us: t,
                left_counts: l,
                right_counts: r,
                heading_urad: h,
                heading_valid: v,
                motion_state: m,
                queue_depth: q,
            })),
        (any::<u16>(), any::<u32>()).prop_map(|(m, c)| Event::MotionDone(MotionDone {
            motion_id: m,
            completed_motions: c
        })),
    ]
}

fn packet() -> impl Strategy<Value = Packet> {
    prop_oneof![
        (any::<u8>(), request()).prop_map(|(s, r)| Packet::request(s, r)),
        (any::<u8>(), response()).prop_map(|(s, r)| Packet::response(s, r)),
        (
            any::<u8>(),
            prop::sample::select(id::REQUESTS.to_vec()),
            any::<u8>(),
            any::<u8>()
        )
            .prop_map(|(s, msg, code, detail)| Packet::nack(
                s,
                msg,
                Nack {
                    code: NackCode::from_byte(code),
                    detail
                }
            )),
        (any::<u8>(), event()).prop_map(|(s, e)| Packet::event(s, e)),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4000, ..ProptestConfig::default() })]

    #[test]
    fn every_message_round_trips(p in packet(), split in any::<prop::sample::Index>()) {
        let bytes = p.to_frame().to_bytes();
        let at = split.index(bytes.len() + 1);
        let mut codec = FrameCodec::new();
        let mut buf = BytesMut::new();
        let mut frames = codec.feed(&mut buf, &bytes[..at]);
        frames.extend(codec.feed(&mut buf, &bytes[at..]));
        prop_assert_eq!(frames.len(), 1);
        prop_assert_eq!(Packet::from_frame(&frames[0]).unwrap(), p);
        prop_assert!(buf.is_empty());
    }
}
