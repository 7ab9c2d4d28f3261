//! iceoryx2 bus adapter (being written).
