//! Validated numbers for scene descriptions: a bad value fails while parsing, so the error
//! carries its place.
//!
//! Each type below deserializes from a plain RON number or tuple and refuses NaN, infinities and
//! out-of-range values. Because the check runs inside serde, `ron` reports the line and column of
//! the offending value (pbrt-v4's `FileLoc` habit, without a second pass over the source).

use glam::Vec3;
use serde::Deserialize;

/// A finite number (no NaN, no infinity).
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Deserialize)]
#[serde(try_from = "f32")]
pub struct Finite(pub f32);

/// A finite number strictly greater than zero (radii, sizes, periods).
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Deserialize)]
#[serde(try_from = "f32")]
pub struct Positive(pub f32);

/// A finite number greater than or equal to zero (blend radii, intensities, offsets).
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Deserialize)]
#[serde(try_from = "f32")]
pub struct NonNegative(pub f32);

/// A finite number in [0, 1] (reflectivity, transparency, weights).
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Deserialize)]
#[serde(try_from = "f32")]
pub struct Unit(pub f32);

/// A 3-vector of finite numbers, written `(x, y, z)`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(try_from = "(f32, f32, f32)")]
pub struct FiniteVec3(pub Vec3);

/// A 3-vector of strictly positive finite numbers (box half-extents, ellipsoid radii, scales).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(try_from = "(f32, f32, f32)")]
pub struct PositiveVec3(pub Vec3);

/// A 3-vector of non-negative finite numbers (colours).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(try_from = "(f32, f32, f32)")]
pub struct Color(pub Vec3);

/// A finite, non-zero direction; normalised on load.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(try_from = "(f32, f32, f32)")]
pub struct Direction(pub Vec3);

fn finite(v: f32) -> Result<f32, String> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("expected a finite number, found {v}"))
    }
}

fn finite3((x, y, z): (f32, f32, f32)) -> Result<Vec3, String> {
    match (finite(x), finite(y), finite(z)) {
        (Ok(x), Ok(y), Ok(z)) => Ok(Vec3::new(x, y, z)),
        _ => Err(format!(
            "expected three finite numbers, found ({x}, {y}, {z})"
        )),
    }
}

impl TryFrom<f32> for Finite {
    type Error = String;
    fn try_from(v: f32) -> Result<Self, String> {
        finite(v).map(Finite)
    }
}

impl TryFrom<f32> for Positive {
    type Error = String;
    fn try_from(v: f32) -> Result<Self, String> {
        match finite(v)? {
            v if v > 0.0 => Ok(Positive(v)),
            v => Err(format!("expected a number > 0, found {v}")),
        }
    }
}

impl TryFrom<f32> for NonNegative {
    type Error = String;
    fn try_from(v: f32) -> Result<Self, String> {
        match finite(v)? {
            v if v >= 0.0 => Ok(NonNegative(v)),
            v => Err(format!("expected a number >= 0, found {v}")),
        }
    }
}

impl TryFrom<f32> for Unit {
    type Error = String;
    fn try_from(v: f32) -> Result<Self, String> {
        match finite(v)? {
            v if (0.0..=1.0).contains(&v) => Ok(Unit(v)),
            v => Err(format!("expected a number in [0, 1], found {v}")),
        }
    }
}

impl TryFrom<(f32, f32, f32)> for FiniteVec3 {
    type Error = String;
    fn try_from(t: (f32, f32, f32)) -> Result<Self, String> {
        finite3(t).map(FiniteVec3)
    }
}

impl TryFrom<(f32, f32, f32)> for PositiveVec3 {
    type Error = String;
    fn try_from(t: (f32, f32, f32)) -> Result<Self, String> {
        let v = finite3(t)?;
        if v.min_element() > 0.0 {
            Ok(PositiveVec3(v))
        } else {
            Err(format!("expected three numbers > 0, found {t:?}"))
        }
    }
}

impl TryFrom<(f32, f32, f32)> for Color {
    type Error = String;
    fn try_from(t: (f32, f32, f32)) -> Result<Self, String> {
        let v = finite3(t)?;
        if v.min_element() >= 0.0 {
            Ok(Color(v))
        } else {
            Err(format!(
                "expected a colour of three numbers >= 0, found {t:?}"
            ))
        }
    }
}

/// `v` as a unit vector: `v` itself when it is one already to float precision (|v|² within
/// 10⁻⁶ of 1), else `v` normalised. Normalising twice need not give the same bits (the
/// normalised (0.3, 1, 0) alternates between two neighbours at every further normalisation),
/// so a unit vector written out and loaded again, a camera's `up` that the viewer prints,
/// must not be normalised again to reload bit for bit. `v` must be finite and non-zero.
pub fn unit(v: Vec3) -> Vec3 {
    if (v.length_squared() - 1.0).abs() <= 1e-6 {
        v
    } else {
        v.normalize()
    }
}

impl TryFrom<(f32, f32, f32)> for Direction {
    type Error = String;
    fn try_from(t: (f32, f32, f32)) -> Result<Self, String> {
        let v = finite3(t)?;
        if v.length_squared() > 1e-12 {
            Ok(Direction(unit(v)))
        } else {
            Err("expected a non-zero direction, found (0, 0, 0)".to_string())
        }
    }
}

impl Default for Color {
    fn default() -> Self {
        Color(Vec3::ONE)
    }
}
