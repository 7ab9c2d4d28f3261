//! Framing (filled below).
