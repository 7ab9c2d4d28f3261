//! Delivery (filled below).
