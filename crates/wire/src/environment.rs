//! The one place a job's environment settings become the tracer's [`Environment`]: the worker
//! (for a farm job) and `pathfarm render` (for a local render) both call [`build_environment`], so
//! the two build the same environment from the same numbers with the same arithmetic, and the
//! farm's image stays bit-identical to the local one.

use crate::api::EnvironmentSettings;
use glam::Vec3;
use pathfarm_tracer::light::{Environment, EnvironmentError};

/// Where an environment's radiance comes from.
#[derive(Clone, Copy, Debug)]
pub enum EnvironmentSource<'a> {
    /// The same linear radiance from every direction.
    Radiance([f32; 3]),
    /// An equirectangular image's bytes (OpenEXR or Radiance `.hdr`).
    Image(&'a [u8]),
}

/// Why a job's environment cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum EnvironmentSettingsError {
    #[error("environment: {0}")]
    Settings(String),
    #[error(transparent)]
    Tracer(#[from] EnvironmentError),
}

fn finite(what: &str, v: f32, non_negative: bool) -> Result<(), EnvironmentSettingsError> {
    if v.is_finite() && (!non_negative || v >= 0.0) {
        Ok(())
    } else {
        Err(EnvironmentSettingsError::Settings(format!(
            "{what} must be finite{} (got {v})",
            if non_negative {
                " and not negative"
            } else {
                ""
            }
        )))
    }
}

/// The tracer's environment from a source, a strength and a rotation (degrees about the up axis):
/// `Environment::uniform(radiance × strength)` or `Environment::from_image(bytes, strength,
/// rotation)`. Every value must be finite; radiance and strength not negative.
pub fn build_environment(
    source: EnvironmentSource<'_>,
    strength: f32,
    rotation_degrees: f32,
) -> Result<Environment, EnvironmentSettingsError> {
    finite("strength", strength, true)?;
    finite("rotation_degrees", rotation_degrees, false)?;
    Ok(match source {
        EnvironmentSource::Radiance(radiance) => {
            for c in radiance {
                finite("radiance", c, true)?;
            }
            Environment::uniform(Vec3::from_array(radiance) * strength)?
        }
        EnvironmentSource::Image(bytes) => {
            Environment::from_image(bytes, strength, rotation_degrees)?
        }
    })
}

impl EnvironmentSettings {
    /// Checks what can be checked without the image: exactly one of `radiance` and `image`,
    /// `image` a lowercase hexadecimal SHA-256, every number finite, radiance and strength not
    /// negative.
    pub fn validate(&self) -> Result<(), EnvironmentSettingsError> {
        let bad = |m: &str| Err(EnvironmentSettingsError::Settings(m.into()));
        match (&self.radiance, &self.image) {
            (Some(_), Some(_)) => return bad("give either `radiance` or `image`, not both"),
            (None, None) => {
                return bad("give `radiance` or `image` (or upload an `environment` part)")
            }
            (Some(radiance), None) => {
                for &c in radiance {
                    finite("radiance", c, true)?;
                }
            }
            (None, Some(hash)) => {
                if !is_sha256_hex(hash) {
                    return bad("`image` must be the lowercase hexadecimal SHA-256 of an image");
                }
            }
        }
        finite("strength", self.strength, true)?;
        finite("rotation_degrees", self.rotation_degrees, false)
    }

    /// The tracer's environment: `image` holds the bytes of the image these settings name (unused
    /// for a uniform radiance).
    pub fn build(&self, image: Option<&[u8]>) -> Result<Environment, EnvironmentSettingsError> {
        self.validate()?;
        let source = match (self.radiance, image) {
            (Some(radiance), _) => EnvironmentSource::Radiance(radiance),
            (None, Some(bytes)) => EnvironmentSource::Image(bytes),
            (None, None) => {
                return Err(EnvironmentSettingsError::Settings(
                    "the environment image's bytes are missing".into(),
                ))
            }
        };
        build_environment(source, self.strength, self.rotation_degrees)
    }
}

/// 64 lowercase hexadecimal digits.
pub fn is_sha256_hex(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_is_radiance_times_strength() {
        let s: EnvironmentSettings =
            serde_json::from_str(r#"{"radiance":[0.1,0.2,0.3],"strength":3}"#).unwrap();
        assert_eq!((s.strength, s.rotation_degrees), (3.0, 0.0));
        let e = s.build(None).unwrap();
        let expected = Vec3::new(0.1, 0.2, 0.3) * 3.0;
        assert_eq!(e.radiance(Vec3::Y).to_array(), expected.to_array());
        let json = serde_json::to_string(&s).unwrap();
        assert_eq!(
            json,
            r#"{"radiance":[0.1,0.2,0.3],"strength":3.0,"rotation_degrees":0.0}"#
        );
        assert_eq!(
            serde_json::from_str::<EnvironmentSettings>(&json).unwrap(),
            s
        );
    }

    #[test]
    fn bad_settings_are_refused() {
        for (json, says) in [
            (r#"{"radiance":[1,1,1],"image":"ab"}"#, "not both"),
            (r#"{"strength":2}"#, "give `radiance` or `image`"),
            (r#"{"radiance":[1,-1,1]}"#, "radiance must be finite"),
            (r#"{"radiance":[1,1,1],"strength":-1}"#, "strength must be"),
            (r#"{"radiance":[1e300,1,1]}"#, "radiance must be finite"),
            (r#"{"image":"ABC"}"#, "SHA-256"),
        ] {
            let s: EnvironmentSettings = serde_json::from_str(json).unwrap();
            let e = s.validate().unwrap_err().to_string();
            assert!(e.contains(says), "{json}: {e}");
        }
        for json in [r#"{"radiance":[1,1]}"#, r#"{"radiance":[1,1,1],"x":1}"#] {
            assert!(
                serde_json::from_str::<EnvironmentSettings>(json).is_err(),
                "{json}"
            );
        }
        let image: EnvironmentSettings =
            serde_json::from_str(&format!(r#"{{"image":"{}"}}"#, "ab".repeat(32))).unwrap();
        image.validate().unwrap();
        assert!(image
            .build(None)
            .unwrap_err()
            .to_string()
            .contains("missing"));
        let e = image.build(Some(b"not an image")).unwrap_err().to_string();
        assert!(e.contains("neither OpenEXR nor Radiance"), "{e}");
    }
}
