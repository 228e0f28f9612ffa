//! Collecting samples one at a time on the device, with coverage.
