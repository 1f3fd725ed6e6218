//! CAN: DBC parsing and signal packing/unpacking.
