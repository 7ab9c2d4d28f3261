//! Hardware abstraction: the [`link::Link`] trait and its transports (UDP, serial, SocketCAN),
//! an in-memory CAN bus, and the [`emulator`] for bandwidth-capped, lossy, delayed links.

pub mod asl;
pub mod can;
pub mod canopen;
pub mod emulator;
pub mod feedlog;
pub mod keyfile;
pub mod kitti;
pub mod link;
pub mod replay;
pub mod sensor;
pub mod serial;
pub mod udp;
pub mod xsens;
