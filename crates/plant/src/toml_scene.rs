//! TOML scenes (std).
