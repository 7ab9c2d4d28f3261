//! Between the front-end's measurements and the team protocol's messages: the conversions live in
//! [`mapper::wire`], shared with the ground station, which builds the same team graph.

pub use mapper::wire::*;
