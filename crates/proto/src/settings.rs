//! The settings a grasp uses, as one versioned postcard value: what `set`/`get` change and
//! what a settings store persists (its bytes are [`Settings::to_bytes`]).

use serde::{Deserialize, Serialize};

use crate::{Error, Estimator, Param, ParamId, StepShape, Unsupported};

/// The grasp settings the host can change between grasps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    /// Layout version of these bytes ([`Settings::LAYOUT`]).
    pub layout: u16,
    /// Torque step ΔT_a after contact (N·m).
    pub delta_ta_nm: f64,
    /// The step's shape.
    pub step_shape: StepShape,
    /// The estimator.
    pub estimator: Estimator,
    /// Largest actuator speed in the approach (rad/s).
    pub approach_speed_rad_s: f64,
    /// Approach torque ceiling (N·m).
    pub approach_max_nm: f64,
    /// Telemetry samples per second (Hz; 0 = off).
    pub telemetry_hz: u16,
    /// Seat the contact in static stages before the step (`false`: step at the contact).
    pub seating: bool,
}

/// Why stored bytes are not settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingsError {
    /// Not a postcard encoding of [`Settings`].
    Malformed,
    /// Written by another layout version.
    Layout {
        /// The bytes' layout.
        found: u16,
    },
    /// A value outside its range.
    OutOfRange(ParamId),
    /// The buffer is too small.
    BufferTooSmall,
}

impl Settings {
    /// Current layout version.
    pub const LAYOUT: u16 = 2;
    /// Largest encoded size (bytes).
    pub const MAX_BYTES: usize = 64;

    /// The value of one parameter (`None` for the scene, which is not a setting).
    pub fn get(&self, id: ParamId) -> Option<Param> {
        Some(match id {
            ParamId::DeltaTa => Param::DeltaTaNm(self.delta_ta_nm),
            ParamId::StepShape => Param::StepShape(self.step_shape),
            ParamId::Estimator => Param::Estimator(self.estimator),
            ParamId::ApproachSpeed => Param::ApproachSpeedRadS(self.approach_speed_rad_s),
            ParamId::ApproachTorqueMax => Param::ApproachMaxNm(self.approach_max_nm),
            ParamId::TelemetryRate => Param::TelemetryHz(self.telemetry_hz),
            ParamId::Seating => Param::Seating(self.seating),
            ParamId::Scene => return None,
        })
    }

    /// Sets one parameter after checking its range; `available` tells which estimators the
    /// build has. The scene is not a setting ([`Error::UnknownChoice`]).
    pub fn set(&mut self, p: &Param, available: &[Estimator]) -> Result<(), Error> {
        p.check()?;
        match *p {
            Param::DeltaTaNm(v) => self.delta_ta_nm = v,
            Param::StepShape(s) => self.step_shape = s,
            Param::Estimator(e) => {
                if !available.contains(&e) {
                    return Err(Error::NotSupported {
                        what: Unsupported::Estimator(e),
                    });
                }
                self.estimator = e
            }
            Param::ApproachSpeedRadS(v) => self.approach_speed_rad_s = v,
            Param::ApproachMaxNm(v) => self.approach_max_nm = v,
            Param::TelemetryHz(h) => self.telemetry_hz = h,
            Param::Seating(v) => self.seating = v,
            Param::Scene(_) => {
                return Err(Error::UnknownChoice {
                    param: ParamId::Scene,
                })
            }
        }
        Ok(())
    }

    /// Checks every value against its range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        for id in ParamId::ALL {
            if let Some(p) = self.get(id) {
                p.check().map_err(|_| SettingsError::OutOfRange(id))?;
            }
        }
        Ok(())
    }

    /// The bytes a store keeps.
    pub fn to_bytes<'a>(&self, buf: &'a mut [u8]) -> Result<&'a mut [u8], SettingsError> {
        postcard::to_slice(self, buf).map_err(|_| SettingsError::BufferTooSmall)
    }

    /// Settings from stored bytes: the layout version and every range checked. Layout 1
    /// (before [`Settings::seating`]) is read as this layout with seating on, what every
    /// firmware of that layout did, so an update keeps the user's settings.
    pub fn from_bytes(bytes: &[u8]) -> Result<Settings, SettingsError> {
        let (layout, _) =
            postcard::take_from_bytes::<u16>(bytes).map_err(|_| SettingsError::Malformed)?;
        let mut buf = [0u8; Self::MAX_BYTES];
        let current: &[u8] = match layout {
            Self::LAYOUT => bytes,
            1 => {
                // Layout 1 is this layout without its last field, a bool (one byte).
                let b = buf
                    .get_mut(..=bytes.len())
                    .ok_or(SettingsError::Malformed)?;
                for (d, s) in b.iter_mut().zip(bytes.iter().chain(&[1])) {
                    *d = *s;
                }
                b
            }
            found => return Err(SettingsError::Layout { found }),
        };
        let mut s: Settings =
            postcard::from_bytes(current).map_err(|_| SettingsError::Malformed)?;
        s.layout = Self::LAYOUT;
        s.validate()?;
        Ok(s)
    }
}
