//! Rover configuration (being written).
