//! Numbers read from files (stage, key and input sections): the range
//! every coordinate and size must fall in, and serde helpers that take
//! exactly as many numbers as a field has. Shared by the stage's and the
//! input layer's configuration, so a coordinate is bounded the same way
//! wherever a file gives one.

use serde::Deserialize;

/// How far from the origin any coordinate of a stage file may be (stage
/// units, mesh units or device units): ten million, beyond any stage or
/// device, and far enough inside f64 that squaring and summing never
/// overflows.
pub const MAX_COORDINATE: f64 = 1e7;

/// The smallest length a stage file may give a size (stage width, stroke
/// width, spacing…): a thousandth of a unit. Below it sizes are a typo,
/// and ratios of them (a curve's length over its spacing) explode.
pub const MIN_SIZE: f64 = 1e-3;

/// Whether `v` is finite and within `lo..=hi`; the problem otherwise.
pub fn within(v: f64, lo: f64, hi: f64) -> Result<(), String> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        let kind = if lo > 0.0 { "a positive" } else { "a" };
        Err(format!("{v} is not {kind} finite number from {lo} to {hi}"))
    }
}

/// Every number of `values` a coordinate (finite, within
/// [`MAX_COORDINATE`] of the origin); the first bad one's index otherwise.
pub fn coordinates<'a>(values: impl IntoIterator<Item = &'a f64>) -> Result<(), (usize, String)> {
    for (i, &v) in values.into_iter().enumerate() {
        within(v, -MAX_COORDINATE, MAX_COORDINATE).map_err(|p| (i, p))?;
    }
    Ok(())
}

/// Exactly `N` numbers, not `N` taken from a longer list (`at = [1, 2, 3]`
/// was read as `[1, 2]`).
pub fn exactly<'de, D: serde::Deserializer<'de>, const N: usize>(
    d: D,
) -> Result<[f64; N], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    let n = v.len();
    v.try_into()
        .map_err(|_| serde::de::Error::invalid_length(n, &format!("{N} numbers").as_str()))
}

/// A list of `[x, y]` pairs, each exactly two numbers.
pub fn pairs<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<[f64; 2]>, D::Error> {
    let v = Vec::<Vec<f64>>::deserialize(d)?;
    v.into_iter()
        .map(|p| {
            let n = p.len();
            p.try_into()
                .map_err(|_| serde::de::Error::invalid_length(n, &"2 numbers [x, y]"))
        })
        .collect()
}

/// [`pairs`], optional.
pub fn some_pairs<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Option<Vec<[f64; 2]>>, D::Error> {
    pairs(d).map(Some)
}

/// [`exactly`] two, optional.
pub fn some_pair<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
    exactly::<D, 2>(d).map(Some)
}
