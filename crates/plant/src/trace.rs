//! CSV traces (std).
