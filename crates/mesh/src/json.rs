//! Reading the project's JSON inputs (meshes, polygons, handles) with errors
//! a person can act on: the file, the line and column, and serde's complaint
//! without its repeated position; a leading byte-order mark is accepted; a
//! point must be exactly `[x, y]` and a triangle exactly `[i, j, k]`.

use serde::de::{DeserializeOwned, Error};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::MeshError;

/// Coordinates beyond this are refused everywhere: inputs are pixels or
/// stage units, and squaring larger values would lose all precision.
pub const MAX_COORDINATE: f64 = 1e9;

/// Parses `text` (named `source` in errors) as a `T`.
pub fn parse<T: DeserializeOwned>(source: &str, text: &str) -> Result<T, MeshError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    serde_json::from_str(text).map_err(|e| {
        let message = e.to_string();
        let position = format!(" at line {} column {}", e.line(), e.column());
        MeshError::Syntax {
            file: source.to_string(),
            line: e.line(),
            column: e.column(),
            message: message
                .strip_suffix(&position)
                .unwrap_or(&message)
                .to_string(),
        }
    })
}

/// A point written `[x, y]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point(pub [f64; 2]);

impl<'de> Deserialize<'de> for Point {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let numbers = Vec::<f64>::deserialize(deserializer)?;
        match numbers[..] {
            [x, y] => Ok(Point([x, y])),
            _ => Err(D::Error::custom(format!(
                "expected a point [x, y], got {} number(s)",
                numbers.len()
            ))),
        }
    }
}

impl Serialize for Point {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.0.serialize(serializer)
    }
}

/// A triangle written `[i, j, k]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Triangle(pub [u32; 3]);

impl<'de> Deserialize<'de> for Triangle {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let indices = Vec::<i64>::deserialize(deserializer)?;
        let [i, j, k] = indices[..] else {
            return Err(D::Error::custom(format!(
                "expected a triangle [i, j, k], got {} index(es)",
                indices.len()
            )));
        };
        let index = |v: i64| {
            u32::try_from(v)
                .map_err(|_| D::Error::custom(format!("vertex index {v} is not a valid index")))
        };
        Ok(Triangle([index(i)?, index(j)?, index(k)?]))
    }
}

impl Serialize for Triangle {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.0.serialize(serializer)
    }
}

/// A number as a person would write it in an error message: `10`, `0.5`,
/// `1e300` — never three hundred digits.
pub fn show(x: f64) -> String {
    if x != 0.0 && (x.abs() >= 1e15 || x.abs() < 1e-4) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// A point as `[x, y]` for error messages.
pub fn show_point(p: glam::DVec2) -> String {
    format!("[{}, {}]", show(p.x), show(p.y))
}
