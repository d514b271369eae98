//! ROS robots: the message types odocal needs ([`msg`]), the ros2_control YAML as a parameter
//! store ([`yaml`]), offline calibration from bags of any storage, ROS 2 or ROS 1 ([`bag`]),
//! and a live base through rosbridge ([`rosbridge`]).

pub mod bag;
pub mod export;
pub mod fragment;
pub mod live;
pub mod msg;
pub mod pose_source;
pub mod rosbridge;
pub mod yaml;
