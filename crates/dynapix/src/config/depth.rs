//! The depth limits of a run's configuration (`sequence.depth_saturation`,
//! `sequence.max_depth`): the camera's unless the configuration sets them.

use serde::de::{DeserializeOwned, Error as _};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// The word that leaves a setting to the camera.
const CAMERA: &str = "camera";

/// A setting that is the camera's (its settings file's, else the default) unless the
/// configuration sets it. Written `"camera"` in a configuration (the default), or the value.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum CameraOr<T> {
    /// The camera's value (else the default).
    #[default]
    Camera,
    /// The configuration's value.
    Set(T),
}

impl<T: Copy> CameraOr<T> {
    /// The configuration's value, `None` when it is the camera's.
    pub fn stated(&self) -> Option<T> {
        match self {
            CameraOr::Camera => None,
            CameraOr::Set(v) => Some(*v),
        }
    }
}

impl<T: Serialize> Serialize for CameraOr<T> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            CameraOr::Camera => s.serialize_str(CAMERA),
            CameraOr::Set(v) => v.serialize(s),
        }
    }
}

impl<'de, T: DeserializeOwned> Deserialize<'de> for CameraOr<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let v = serde_json::Value::deserialize(d)?;
        if v.as_str() == Some(CAMERA) {
            return Ok(CameraOr::Camera);
        }
        serde_json::from_value(v)
            .map(CameraOr::Set)
            .map_err(|e| D::Error::custom(format!("{e} (or \"{CAMERA}\": the camera's value)")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_word_null_and_values_read_back_as_written() {
        let read = |t: &str| serde_json::from_str::<CameraOr<Option<u16>>>(t);
        assert_eq!(read("\"camera\"").unwrap(), CameraOr::Camera);
        assert_eq!(read("null").unwrap(), CameraOr::Set(None));
        assert_eq!(read("4095").unwrap(), CameraOr::Set(Some(4095)));
        let e = read("70000").unwrap_err().to_string();
        assert!(e.contains("camera"), "{e}");
        assert!(read("\"cam\"").is_err());
        for v in [
            CameraOr::Camera,
            CameraOr::Set(None),
            CameraOr::Set(Some(7)),
        ] {
            let text = serde_json::to_string(&v).unwrap();
            assert_eq!(read(&text).unwrap(), v);
        }
        assert_eq!(CameraOr::Set(2.5f32).stated(), Some(2.5));
        assert_eq!(CameraOr::<f32>::Camera.stated(), None);
    }
}
