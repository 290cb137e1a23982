//! rtf-calib: targetless RGB-thermal calibration.
