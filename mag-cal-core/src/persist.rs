//! Storing a calibration as bytes: magic, version, parameters, CRC.
