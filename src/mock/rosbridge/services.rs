//! The services the mock robot answers through `call_service`: rosapi's view of the graph
//! (`/rosapi/topics`, `topics_for_type`, `topic_type`, `publishers`, `subscribers`,
//! `services`, `nodes`, `node_details`, `get_time`, `get_ros_version`) and the controller
//! node's parameter services as `rcl_interfaces` defines them (`get_parameters`,
//! `set_parameters`, `set_parameters_atomically`, `list_parameters`, `describe_parameters`,
//! `get_parameter_types`), with rclcpp's answers: `get_parameters` of an undeclared name gives
//! no values, `set_parameters` refuses an undeclared name, another type or a read-only
//! parameter ([`MockRosConfig::read_only_parameters`]) with rclcpp's reasons, and what a
//! parameter callback refuses ([`MockRosConfig::refuse_parameter_sets`]); it accepts any other
//! value of the declared type (Humble's controller declares no ranges).
//!
//! Replies carry `id` only when the request did, as `rosbridge_server` does.

use super::conn::canonical_type;
use super::{lock, MockRosConfig, MockRosState};
use crate::ros::msg::types;
use crate::ros::yaml::DiffDriveConfig;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::sync::Mutex;

/// A ROS 2 parameter's value (`rcl_interfaces/msg/ParameterValue`, the types a
/// `diff_drive_controller` declares).
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    /// `PARAMETER_BOOL` (1).
    Bool(bool),
    /// `PARAMETER_INTEGER` (2).
    Integer(i64),
    /// `PARAMETER_DOUBLE` (3).
    Double(f64),
    /// `PARAMETER_STRING` (4).
    String(String),
    /// `PARAMETER_DOUBLE_ARRAY` (8).
    DoubleArray(Vec<f64>),
    /// `PARAMETER_STRING_ARRAY` (9).
    StringArray(Vec<String>),
}

impl ParamValue {
    /// The `ParameterType` number.
    pub fn type_id(&self) -> u8 {
        match self {
            ParamValue::Bool(_) => 1,
            ParamValue::Integer(_) => 2,
            ParamValue::Double(_) => 3,
            ParamValue::String(_) => 4,
            ParamValue::DoubleArray(_) => 8,
            ParamValue::StringArray(_) => 9,
        }
    }

    fn type_name(type_id: u64) -> &'static str {
        match type_id {
            0 => "not set",
            1 => "bool",
            2 => "integer",
            3 => "double",
            4 => "string",
            5 => "byte_array",
            6 => "bool_array",
            7 => "integer_array",
            8 => "double_array",
            9 => "string_array",
            _ => "unknown",
        }
    }

    /// As rosbridge writes a `ParameterValue`: every field, the unused ones empty.
    pub fn to_json(&self) -> Value {
        let mut v = json!({
            "type": self.type_id(), "bool_value": false, "integer_value": 0,
            "double_value": 0.0, "string_value": "", "byte_array_value": [],
            "bool_array_value": [], "integer_array_value": [], "double_array_value": [],
            "string_array_value": []
        });
        match self {
            ParamValue::Bool(b) => v["bool_value"] = json!(b),
            ParamValue::Integer(i) => v["integer_value"] = json!(i),
            // A NaN default (the velocity limits) is written as null, as rosbridge does.
            ParamValue::Double(d) => v["double_value"] = json!(d),
            ParamValue::String(s) => v["string_value"] = json!(s),
            ParamValue::DoubleArray(a) => v["double_array_value"] = json!(a),
            ParamValue::StringArray(a) => v["string_array_value"] = json!(a),
        }
        v
    }

    /// The value of a request's `ParameterValue`, when it is of type `type_id`.
    fn from_json(v: &Value) -> Result<ParamValue, u64> {
        let t = v.get("type").and_then(Value::as_u64).unwrap_or(0);
        let field = |name: &str| v.get(name).cloned().unwrap_or(Value::Null);
        let value = match t {
            1 => field("bool_value").as_bool().map(ParamValue::Bool),
            2 => field("integer_value").as_i64().map(ParamValue::Integer),
            3 => Some(ParamValue::Double(
                field("double_value").as_f64().unwrap_or(f64::NAN),
            )),
            4 => field("string_value")
                .as_str()
                .map(|s| ParamValue::String(s.into())),
            8 => serde_json::from_value(field("double_array_value"))
                .ok()
                .map(ParamValue::DoubleArray),
            9 => serde_json::from_value(field("string_array_value"))
                .ok()
                .map(ParamValue::StringArray),
            _ => None,
        };
        value.ok_or(t)
    }
}

/// The parameters `diff_drive_controller` (ros2_controllers, Humble) declares, with the YAML's
/// values where it gives them; `use_stamped_vel` says which twist its `cmd_vel` takes.
pub fn controller_parameters(c: &DiffDriveConfig, stamped: bool) -> BTreeMap<String, ParamValue> {
    use ParamValue::*;
    let mut p: BTreeMap<std::string::String, ParamValue> = [
        ("left_wheel_names", StringArray(c.left_wheel_names.clone())),
        (
            "right_wheel_names",
            StringArray(c.right_wheel_names.clone()),
        ),
        ("wheel_separation", Double(c.wheel_separation_m)),
        ("wheels_per_side", Integer(0)),
        ("wheel_radius", Double(c.wheel_radius_m)),
        (
            "wheel_separation_multiplier",
            Double(c.separation_multiplier),
        ),
        (
            "left_wheel_radius_multiplier",
            Double(c.left_radius_multiplier),
        ),
        (
            "right_wheel_radius_multiplier",
            Double(c.right_radius_multiplier),
        ),
        ("odom_frame_id", String("odom".into())),
        ("base_frame_id", String("base_link".into())),
        ("pose_covariance_diagonal", DoubleArray(vec![0.0; 6])),
        ("twist_covariance_diagonal", DoubleArray(vec![0.0; 6])),
        ("open_loop", Bool(false)),
        ("position_feedback", Bool(true)),
        ("enable_odom_tf", Bool(true)),
        (
            "cmd_vel_timeout",
            Double(c.cmd_vel_timeout_s.unwrap_or(0.5)),
        ),
        ("publish_limited_velocity", Bool(false)),
        ("velocity_rolling_window_size", Integer(10)),
        ("use_stamped_vel", Bool(stamped)),
        ("publish_rate", Double(50.0)),
        ("use_sim_time", Bool(false)),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    for axis in ["linear.x", "angular.z"] {
        for flag in [
            "has_velocity_limits",
            "has_acceleration_limits",
            "has_jerk_limits",
        ] {
            p.insert(format!("{axis}.{flag}"), Bool(false));
        }
        for limit in ["velocity", "acceleration", "jerk"] {
            for end in ["max", "min"] {
                p.insert(format!("{axis}.{end}_{limit}"), Double(f64::NAN));
            }
        }
    }
    p
}

/// The robot's nodes.
const ROSBRIDGE_NODE: &str = "/rosbridge_websocket";
const BROADCASTER_NODE: &str = "/joint_state_broadcaster";
const IMU_NODE: &str = "/imu_driver";

fn controller_node(cfg: &MockRosConfig) -> String {
    format!("/{}", cfg.controller.controller)
}

fn cmd_vel_type(cfg: &MockRosConfig) -> &'static str {
    if cfg.cmd_vel_stamped {
        types::TWIST_STAMPED
    } else {
        types::TWIST
    }
}

/// Every topic of the graph with its type: the robot's and what clients advertised.
pub(super) fn topic_types(
    cfg: &MockRosConfig,
    state: &Mutex<MockRosState>,
) -> BTreeMap<String, String> {
    let mut t: BTreeMap<String, String> = lock(state).advertised.clone();
    for (topic, kind) in [
        ("/joint_states", types::JOINT_STATE),
        ("/imu", types::IMU),
        ("/odom", types::ODOMETRY),
        ("/rosout", "rcl_interfaces/msg/Log"),
        (cfg.cmd_vel.as_str(), cmd_vel_type(cfg)),
    ] {
        t.insert(topic.to_string(), kind.to_string());
    }
    if let Some(l) = &cfg.localization {
        t.insert(
            l.topic.clone(),
            types::POSE_WITH_COVARIANCE_STAMPED.to_string(),
        );
    }
    t
}

/// Who publishes and who subscribes to `topic`.
fn graph_of(
    cfg: &MockRosConfig,
    state: &Mutex<MockRosState>,
    topic: &str,
) -> (Vec<String>, Vec<String>) {
    let ctrl = controller_node(cfg);
    let advertised = lock(state).advertised.contains_key(topic);
    let mut publishers: Vec<String> = match topic {
        "/joint_states" => vec![BROADCASTER_NODE.into()],
        "/imu" => vec![IMU_NODE.into()],
        "/odom" => vec![ctrl.clone()],
        "/rosout" => vec![ctrl.clone(), BROADCASTER_NODE.into(), IMU_NODE.into()],
        t if cfg.localization.as_ref().is_some_and(|l| l.topic == t) => vec!["/amcl".into()],
        _ => vec![],
    };
    if advertised {
        publishers.push(ROSBRIDGE_NODE.into());
    }
    let subscribers = if topic == cfg.cmd_vel {
        vec![ctrl]
    } else {
        vec![]
    };
    (publishers, subscribers)
}

fn nodes(cfg: &MockRosConfig) -> Vec<String> {
    vec![
        "/controller_manager".into(),
        controller_node(cfg),
        BROADCASTER_NODE.into(),
        IMU_NODE.into(),
        "/rosapi".into(),
        ROSBRIDGE_NODE.into(),
    ]
}

const PARAMETER_SERVICES: [(&str, &str); 6] = [
    ("get_parameters", "rcl_interfaces/srv/GetParameters"),
    ("set_parameters", "rcl_interfaces/srv/SetParameters"),
    (
        "set_parameters_atomically",
        "rcl_interfaces/srv/SetParametersAtomically",
    ),
    ("list_parameters", "rcl_interfaces/srv/ListParameters"),
    (
        "describe_parameters",
        "rcl_interfaces/srv/DescribeParameters",
    ),
    (
        "get_parameter_types",
        "rcl_interfaces/srv/GetParameterTypes",
    ),
];

const ROSAPI_SERVICES: [&str; 10] = [
    "topics",
    "topics_for_type",
    "topic_type",
    "publishers",
    "subscribers",
    "services",
    "nodes",
    "node_details",
    "get_time",
    "get_ros_version",
];

/// Every service with its type.
fn services(cfg: &MockRosConfig) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = ROSAPI_SERVICES
        .iter()
        .map(|s| {
            let kind = s
                .split('_')
                .map(|w| {
                    let mut c = w.chars();
                    c.next()
                        .map(|f| f.to_ascii_uppercase().to_string() + c.as_str())
                        .unwrap_or_default()
                })
                .collect::<String>()
                // rosapi spells it GetROSVersion.
                .replace("Ros", "ROS");
            (format!("/rosapi/{s}"), format!("rosapi_msgs/srv/{kind}"))
        })
        .collect();
    for node in [controller_node(cfg), BROADCASTER_NODE.into()] {
        for (s, t) in PARAMETER_SERVICES {
            out.push((format!("{node}/{s}"), t.into()));
        }
    }
    out
}

/// Answers one `call_service`.
pub(super) fn call_service(op: &Value, cfg: &MockRosConfig, state: &Mutex<MockRosState>) -> Value {
    let service = op
        .get("service")
        .and_then(Value::as_str)
        .unwrap_or("")
        .to_string();
    let args = op.get("args").cloned().unwrap_or(json!({}));
    let result = answer(&service, &args, cfg, state);
    let mut reply = match result {
        Ok(values) => {
            json!({"op": "service_response", "service": service, "values": values, "result": true})
        }
        Err(why) => {
            json!({"op": "service_response", "service": service, "values": why, "result": false})
        }
    };
    if let Some(id) = op.get("id") {
        reply["id"] = id.clone();
    }
    reply
}

fn arg<'a>(args: &'a Value, name: &str) -> &'a str {
    args.get(name).and_then(Value::as_str).unwrap_or("")
}

fn answer(
    service: &str,
    args: &Value,
    cfg: &MockRosConfig,
    state: &Mutex<MockRosState>,
) -> Result<Value, String> {
    let ctrl = controller_node(cfg);
    if let Some(name) = service.strip_prefix(&format!("{ctrl}/")) {
        return parameters(name, args, cfg, state).ok_or_else(|| missing(service));
    }
    if let Some(name) = service.strip_prefix(&format!("{BROADCASTER_NODE}/")) {
        // A node with parameters odocal has no business with: it answers, empty.
        return match name {
            "list_parameters" => Ok(json!({"result": {"names": ["use_sim_time"], "prefixes": []}})),
            "get_parameters" => Ok(json!({"values": []})),
            _ => Err(missing(service)),
        };
    }
    let topics = topic_types(cfg, state);
    Ok(match service {
        "/rosapi/topics" => json!({
            "topics": topics.keys().collect::<Vec<_>>(),
            "types": topics.values().collect::<Vec<_>>(),
        }),
        "/rosapi/topics_for_type" => {
            let want = canonical_type(arg(args, "type"));
            json!({"topics": topics.iter().filter(|(_, t)| **t == want).map(|(n, _)| n).collect::<Vec<_>>()})
        }
        "/rosapi/topic_type" => {
            json!({"type": topics.get(arg(args, "topic")).cloned().unwrap_or_default()})
        }
        "/rosapi/publishers" => json!({"publishers": graph_of(cfg, state, arg(args, "topic")).0}),
        "/rosapi/subscribers" => {
            json!({"subscribers": graph_of(cfg, state, arg(args, "topic")).1})
        }
        "/rosapi/services" => {
            json!({"services": services(cfg).into_iter().map(|(s, _)| s).collect::<Vec<_>>()})
        }
        "/rosapi/nodes" => json!({"nodes": nodes(cfg)}),
        "/rosapi/node_details" => {
            let node = arg(args, "node");
            let (mut publishing, mut subscribing) = (Vec::new(), Vec::new());
            for topic in topics.keys() {
                let (p, s) = graph_of(cfg, state, topic);
                if p.iter().any(|n| n == node) {
                    publishing.push(topic.clone());
                }
                if s.iter().any(|n| n == node) {
                    subscribing.push(topic.clone());
                }
            }
            let prefix = format!("{node}/");
            let services: Vec<String> = services(cfg)
                .into_iter()
                .map(|(s, _)| s)
                .filter(|s| s.starts_with(&prefix))
                .collect();
            json!({"publishing": publishing, "subscribing": subscribing, "services": services})
        }
        "/rosapi/get_time" => {
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap_or_default();
            json!({"time": {"sec": now.as_secs(), "nanosec": now.subsec_nanos()}})
        }
        "/rosapi/get_ros_version" => json!({"version": 2, "distro": "humble"}),
        _ => return Err(missing(service)),
    })
}

fn missing(service: &str) -> String {
    format!("Service {service} does not exist")
}

/// The controller node's parameter services, or `None` for another name.
fn parameters(
    name: &str,
    args: &Value,
    cfg: &MockRosConfig,
    state: &Mutex<MockRosState>,
) -> Option<Value> {
    let names = || -> Vec<String> {
        args.get("names")
            .and_then(|n| serde_json::from_value(n.clone()).ok())
            .unwrap_or_default()
    };
    let mut s = lock(state);
    Some(match name {
        "get_parameters" => {
            // rclcpp: one undeclared name and the answer is empty.
            let values: Option<Vec<Value>> = names()
                .iter()
                .map(|n| s.params.get(n).map(ParamValue::to_json))
                .collect();
            json!({"values": values.unwrap_or_default()})
        }
        "get_parameter_types" => {
            let types: Option<Vec<u8>> = names()
                .iter()
                .map(|n| s.params.get(n).map(ParamValue::type_id))
                .collect();
            json!({"types": types.unwrap_or_default()})
        }
        "describe_parameters" => describe_parameters(&s.params, &names(), cfg),
        "list_parameters" => list_parameters(&s.params, args),
        "set_parameters" | "set_parameters_atomically" => set_parameters(name, args, cfg, &mut s),
        _ => return None,
    })
}

/// Whether the controller's parameter `n` is declared read-only.
fn read_only(cfg: &MockRosConfig, n: &str) -> bool {
    cfg.read_only_parameters.iter().any(|r| r == n)
}

/// `describe_parameters`: a descriptor per name, or none at all if one is undeclared.
fn describe_parameters(
    params: &BTreeMap<String, ParamValue>,
    names: &[String],
    cfg: &MockRosConfig,
) -> Value {
    let descriptors: Option<Vec<Value>> = names
        .iter()
        .map(|n| {
            params.get(n).map(|v| {
                json!({"name": n, "type": v.type_id(), "description": "",
                    "additional_constraints": "", "read_only": read_only(cfg, n),
                    "dynamic_typing": false, "floating_point_range": [],
                    "integer_range": []})
            })
        })
        .collect();
    json!({"descriptors": descriptors.unwrap_or_default()})
}

/// `list_parameters`: the names under the requested prefixes (all without any) and their groups.
fn list_parameters(params: &BTreeMap<String, ParamValue>, args: &Value) -> Value {
    let prefixes: Vec<String> = args
        .get("prefixes")
        .and_then(|p| serde_json::from_value(p.clone()).ok())
        .unwrap_or_default();
    let names: Vec<&String> = params
        .keys()
        .filter(|n| {
            prefixes.is_empty()
                || prefixes
                    .iter()
                    .any(|p| n.starts_with(&format!("{p}.")) || *n == p)
        })
        .collect();
    let mut groups: Vec<&str> = names
        .iter()
        .filter_map(|n| n.rsplit_once('.').map(|(g, _)| g))
        .collect();
    groups.dedup();
    json!({"result": {"names": names, "prefixes": groups}})
}

/// `set_parameters` and `set_parameters_atomically` (`name`): checks each requested value as
/// rclcpp would, applies what the service's semantics allow and answers with the results.
fn set_parameters(name: &str, args: &Value, cfg: &MockRosConfig, s: &mut MockRosState) -> Value {
    let requests: Vec<Value> = args
        .get("parameters")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    let mut results = Vec::new();
    let mut staged = s.params.clone();
    for p in &requests {
        results.push(match stage_parameter(&mut staged, p, cfg) {
            Ok(()) => json!({"successful": true, "reason": ""}),
            Err(reason) => json!({"successful": false, "reason": reason}),
        });
    }
    let all_ok = results.iter().all(|r| r["successful"] == json!(true));
    s.counters.parameter_sets += 1;
    if name == "set_parameters_atomically" {
        if all_ok {
            apply(s, staged);
            json!({"result": {"successful": true, "reason": ""}})
        } else {
            json!({"result": {"successful": false, "reason": "One or more parameters were not declared before setting"}})
        }
    } else {
        // Each applied on its own: the successful ones stand.
        let mut kept = s.params.clone();
        for (p, r) in requests.iter().zip(&results) {
            if r["successful"] == json!(true) {
                let n = p.get("name").and_then(Value::as_str).unwrap_or("");
                if let Some(v) = staged.get(n) {
                    kept.insert(n.to_string(), v.clone());
                }
            }
        }
        apply(s, kept);
        json!({"results": results})
    }
}

/// Checks one requested parameter `p` against the declared ones and stages its value in
/// `staged`, or gives rclcpp's reason for refusing it.
fn stage_parameter(
    staged: &mut BTreeMap<String, ParamValue>,
    p: &Value,
    cfg: &MockRosConfig,
) -> Result<(), String> {
    let n = p.get("name").and_then(Value::as_str).unwrap_or("");
    match (staged.get(n), p.get("value").map(ParamValue::from_json)) {
        (None, _) => Err(format!(
            "parameter '{n}' cannot be set because it was not declared"
        )),
        (Some(_), _) if read_only(cfg, n) => Err(format!(
            "parameter '{n}' cannot be set because it is read-only"
        )),
        (Some(_), _) if cfg.refuse_parameter_sets.is_some() => {
            Err(cfg.refuse_parameter_sets.clone().unwrap_or_default())
        }
        (Some(have), Some(Ok(v))) if v.type_id() == have.type_id() => {
            staged.insert(n.to_string(), v);
            Ok(())
        }
        (Some(have), got) => {
            let t = match got {
                Some(Ok(v)) => u64::from(v.type_id()),
                Some(Err(t)) => t,
                None => 0,
            };
            Err(format!(
                "Wrong parameter type, parameter {{{n}}} is of type {{{}}}, setting \
                 it to {{{}}} is not allowed.",
                ParamValue::type_name(u64::from(have.type_id())),
                ParamValue::type_name(t)
            ))
        }
    }
}

/// New parameter values, and the geometry they give the running controller when it is a
/// robot's (a controller given a negative wheel separation holds it, but drives with the last
/// geometry that made sense).
fn apply(s: &mut MockRosState, params: BTreeMap<String, ParamValue>) {
    let double = |k: &str| match params.get(k) {
        Some(ParamValue::Double(d)) => Some(*d),
        _ => None,
    };
    let mut c = s.controller.clone();
    let fields: [(&str, &mut f64); 5] = [
        ("wheel_separation", &mut c.wheel_separation_m),
        ("wheel_radius", &mut c.wheel_radius_m),
        ("wheel_separation_multiplier", &mut c.separation_multiplier),
        (
            "left_wheel_radius_multiplier",
            &mut c.left_radius_multiplier,
        ),
        (
            "right_wheel_radius_multiplier",
            &mut c.right_radius_multiplier,
        ),
    ];
    for (k, slot) in fields {
        if let Some(v) = double(k) {
            *slot = v;
        }
    }
    s.params = params;
    let g = c.effective();
    if g.check_physical().is_ok() && s.sim.set_configured(g).is_ok() {
        s.controller = c;
    }
}
