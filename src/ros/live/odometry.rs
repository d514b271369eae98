//! The robot's own odometry as the drive follows it, integrated in the background: the wheel
//! joint angles with the configured geometry, or the controller's `/odom`; messages that fail
//! validation are counted per topic and named when a motion stalls.

use super::*;

/// The drive's odometry now.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct Odo {
    /// Cumulative forward distance (m).
    pub(super) distance_m: f64,
    /// Cumulative turn (rad).
    pub(super) turn_rad: f64,
    /// Messages integrated.
    pub(super) samples: u64,
    /// Message time of the last one (s).
    pub(super) stamp_s: f64,
    /// Message time since which the wheels have not moved (s).
    pub(super) still_since_s: Option<f64>,
}

/// Messages that arrived but could not be used or were dropped, per topic and reason: how
/// many and an example, so that a silent topic and a topic whose messages odocal cannot read
/// are told apart, and a run's report counts every sample the checks dropped
/// ([`RosDrive`]'s diagnostics).
#[derive(Clone, Default)]
pub(super) struct Rejects(Arc<std::sync::Mutex<std::collections::BTreeMap<String, Vec<Rejected>>>>);

pub(super) struct Rejected {
    pub(super) count: u64,
    pub(super) reason: String,
    pub(super) example: String,
}

impl Rejects {
    pub(super) fn note(&self, topic: &str, reason: String, msg: &Value) {
        let mut map = self.0.lock().unwrap_or_else(|p| p.into_inner());
        let reasons = map.entry(topic.to_string()).or_default();
        match reasons.iter_mut().find(|r| r.reason == reason) {
            Some(r) => r.count += 1,
            None => reasons.push(Rejected {
                count: 1,
                reason,
                example: msg.to_string().chars().take(240).collect(),
            }),
        }
    }

    pub(super) fn describe(&self, topic: &str) -> Option<String> {
        let map = self.0.lock().unwrap_or_else(|p| p.into_inner());
        let reasons = map.get(topic).filter(|r| !r.is_empty())?;
        let count: u64 = reasons.iter().map(|r| r.count).sum();
        let why: Vec<String> = reasons
            .iter()
            .map(|r| format!("{} ({})", r.reason, r.count))
            .collect();
        Some(format!(
            "{count} message(s) arrived and none could be used: {}; e.g. {}",
            why.join("; "),
            reasons[0].example
        ))
    }

    /// Every topic's drops, for a report: `{topic: [{reason, count}]}`.
    pub(super) fn summary(&self) -> Value {
        let map = self.0.lock().unwrap_or_else(|p| p.into_inner());
        Value::Object(
            map.iter()
                .map(|(topic, reasons)| {
                    let list = reasons
                        .iter()
                        .map(|r| json!({ "reason": r.reason, "count": r.count }))
                        .collect();
                    (topic.clone(), Value::Array(list))
                })
                .collect(),
        )
    }
}

pub(super) fn advance(odo: &mut Odo, stamp: f64, step: Displacement) {
    let (ds, dth) = (step.distance_m, step.turn_rad);
    let dt = (stamp - odo.stamp_s).max(1e-6);
    let moving = ds.abs() / dt > 0.002 || dth.abs() / dt > 0.01;
    odo.distance_m += ds;
    odo.turn_rad += dth;
    odo.samples += 1;
    odo.stamp_s = stamp;
    odo.still_since_s = match (moving, odo.still_since_s) {
        (true, _) => None,
        (false, Some(s)) => Some(s),
        (false, None) => Some(stamp),
    };
}

pub(super) async fn integrate_joints(
    mut rx: tokio::sync::broadcast::Receiver<Value>,
    (topic, rejects): (String, Rejects),
    geometry: Geometry,
    left: Option<String>,
    right: Option<String>,
    tx: watch::Sender<Odo>,
    travel: Fanout<TravelSample>,
) {
    let mut last: Option<(f64, f64)> = None;
    let mut odo = Odo::default();
    let mut check = LiveJoints::default();
    loop {
        let Some(v) = next_message(&mut rx).await else {
            return;
        };
        let js = match decode::<JointState>(&v) {
            Ok(js) => js,
            Err(why) => {
                rejects.note(&topic, why, &v);
                continue;
            }
        };
        let Some((l, r)) = js.wheel_indices(&left, &right) else {
            let want = match (&left, &right) {
                (Some(l), Some(r)) => format!("`{l}` and `{r}`"),
                _ => "one name with \"left\" and one with \"right\"".into(),
            };
            let why = format!("no wheel joints {want} among {:?}", js.name);
            rejects.note(&topic, why, &v);
            continue;
        };
        let (Some(&lp), Some(&rp)) = (js.position.get(l), js.position.get(r)) else {
            rejects.note(&topic, "fewer positions than names".into(), &v);
            continue;
        };
        let stamp = stamp_of(&v).unwrap_or(odo.stamp_s);
        // The checks a bag's joints get, one message at a time.
        let (settled, verdict) = check.check(stamp, (lp, rp));
        match settled {
            Some(Verdict::Drop(why)) => rejects.note(&topic, why.into(), &v),
            Some(Verdict::Restart) => rejects.note(
                &topic,
                "a jump that stayed (the driver reset its counts?): the step across it is not \
                 travel"
                    .into(),
                &v,
            ),
            _ => {}
        }
        match verdict {
            Verdict::Drop(why) => {
                rejects.note(&topic, why.into(), &v);
                continue;
            }
            Verdict::Hold => continue,
            Verdict::Restart if last.is_some() => {
                last = Some((lp, rp));
                odo.stamp_s = stamp;
                let _ = tx.send(odo);
                continue;
            }
            Verdict::Restart | Verdict::Keep => {}
        }
        let g = effective(&geometry);
        if let Some((l0, r0)) = last {
            let (sl, sr) = g.travel_m(
                super::super::msg::angle_step(l0, lp),
                super::super::msg::angle_step(r0, rp),
            );
            advance(
                &mut odo,
                stamp,
                Displacement::of_wheels(sl, sr, g.wheelbase_m),
            );
            travel.send(&TravelSample {
                time_s: stamp,
                left_m: sl,
                right_m: sr,
            });
        } else {
            odo.samples = 1;
            odo.stamp_s = stamp;
        }
        last = Some((lp, rp));
        let _ = tx.send(odo);
    }
}

pub(super) async fn integrate_odom(
    mut rx: tokio::sync::broadcast::Receiver<Value>,
    (topic, rejects): (String, Rejects),
    geometry: Geometry,
    tx: watch::Sender<Odo>,
    travel: Fanout<TravelSample>,
) {
    let mut last: Option<(f64, f64, f64)> = None;
    let mut odo = Odo::default();
    let mut forward = Forward::default();
    loop {
        let Some(v) = next_message(&mut rx).await else {
            return;
        };
        let o = match decode::<Odometry>(&v) {
            Ok(o) => o,
            Err(why) => {
                rejects.note(&topic, why, &v);
                continue;
            }
        };
        let yaw = match yaw_of(&o.pose.pose.orientation) {
            Ok(yaw) => yaw,
            Err(why) => {
                rejects.note(&topic, format!("pose.pose.orientation: {why}"), &v);
                continue;
            }
        };
        let (x, y) = (o.pose.pose.position.x, o.pose.pose.position.y);
        if !(x.abs() <= MAX_POSITION_M && y.abs() <= MAX_POSITION_M) {
            rejects.note(
                &topic,
                format!("pose.pose.position is not a number within ±{MAX_POSITION_M:e} m"),
                &v,
            );
            continue;
        }
        let stamp = stamp_of(&v).unwrap_or(odo.stamp_s);
        if let Verdict::Drop(why) = forward.check(stamp) {
            rejects.note(&topic, why.into(), &v);
            continue;
        }
        if let Some((x0, y0, yaw0)) = last {
            let dth = wrap_angle(yaw - yaw0);
            let mid = yaw0 + 0.5 * dth;
            let step = Displacement {
                distance_m: (x - x0) * mid.cos() + (y - y0) * mid.sin(),
                turn_rad: dth,
            };
            advance(&mut odo, stamp, step);
            let (left_m, right_m) = step.wheels(effective(&geometry).wheelbase_m);
            travel.send(&TravelSample {
                time_s: stamp,
                left_m,
                right_m,
            });
        } else {
            odo.samples = 1;
            odo.stamp_s = stamp;
        }
        last = Some((x, y, yaw));
        let _ = tx.send(odo);
    }
}
