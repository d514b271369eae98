//! RoboClaw (Basicmicro) motor controllers over packet serial, as a [`crate::base::Drive`].
//! [`packet`] has the bytes; [`client`] the transactions; [`drive`] the open-loop motions.

pub mod client;
pub mod drive;
pub mod packet;
