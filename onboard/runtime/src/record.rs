//! Bus recording and replay (being written).
