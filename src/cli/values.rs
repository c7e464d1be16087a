//! Value parsers of numeric arguments: each refuses, before anything is read or written, a value
//! that would write nonsense (a layer no printer counts, a NaN, a negative margin), naming the
//! valid range.

use anyhow::{bail, Result};
use layerwise::shot::MAX_LAYER;

/// A finite number that `fits`; otherwise `range` says what is valid.
fn number(text: &str, fits: impl Fn(f64) -> bool, range: &str) -> Result<f64> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && fits(v) => Ok(v),
        _ => bail!("`{text}` mm: {range}"),
    }
}

/// A printer layer: 1 to 99999 (file names hold 5 digits).
pub fn layer(text: &str) -> Result<u32> {
    match text.trim().parse::<u32>() {
        Ok(v) if (1..=MAX_LAYER).contains(&v) => Ok(v),
        _ => {
            bail!("`{text}` is not a layer: layers are 1 to {MAX_LAYER} (file names hold 5 digits)")
        }
    }
}

/// A calibration's error limit: more than 0 and at most 100 mm.
pub fn max_error_mm(text: &str) -> Result<f64> {
    number(
        text,
        |v| v > 0.0 && v <= 100.0,
        "the error limit is more than 0 and at most 100 mm",
    )
}

/// A build's layer count: 1 to 99999.
pub fn layer_count(text: &str) -> Result<u32> {
    match text.trim().parse::<u32>() {
        Ok(v) if (1..=MAX_LAYER).contains(&v) => Ok(v),
        _ => {
            bail!("`{text}` layers: a build has 1 to {MAX_LAYER} layers (file names hold 5 digits)")
        }
    }
}

/// A powder layer's thickness: more than 0 and at most 10 mm, as `build.layer_thickness_mm`.
pub fn layer_thickness_mm(text: &str) -> Result<f64> {
    number(
        text,
        |v| v > 0.0 && v <= 10.0,
        "a layer thickness is more than 0 and at most 10 mm (a powder layer is about 0.03)",
    )
}

/// A margin: 0 to 1000 mm.
pub fn margin_mm(text: &str) -> Result<f64> {
    number(
        text,
        |v| (0.0..=1000.0).contains(&v),
        "a margin is 0 to 1000 mm",
    )
}

/// A coordinate in mm: finite and within a kilometre of the origin.
pub fn coordinate_mm(text: &str) -> Result<f64> {
    number(
        text,
        |v| v.abs() <= 1e6,
        "a coordinate is a finite number, -1000000 to 1000000 mm",
    )
}

/// Image pyramid levels: 1 to 12 (a 4096-pixel image halves to 1 pixel in 12).
pub fn pyramid_levels(text: &str) -> Result<usize> {
    match text.trim().parse::<usize>() {
        Ok(v) if (1..=12).contains(&v) => Ok(v),
        _ => bail!("`{text}` pyramid levels: give 1 to 12"),
    }
}

/// A patch side: an odd number of pixels up to 4095, so the flaw is the centre pixel.
pub fn patch_px(text: &str) -> Result<usize> {
    match text.trim().parse::<usize>() {
        Ok(v) if v % 2 == 1 && v <= 4095 => Ok(v),
        _ => bail!("patch size `{text}` px: give an odd number of pixels up to 4095, so the flaw is the centre pixel"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_refuses_outside_its_range_and_names_it() {
        assert_eq!(layer("7").unwrap(), 7);
        for bad in ["0", "4294967295", "100000", "-1", "x"] {
            assert!(
                layer(bad).unwrap_err().to_string().contains("1 to 99999"),
                "{bad}"
            );
        }
        assert!(layer_count("0").is_err() && layer_count("100000").is_err());
        assert_eq!(layer_thickness_mm("0.03").unwrap(), 0.03);
        for bad in ["0", "nan", "1e308", "-0.03", "inf"] {
            assert!(layer_thickness_mm(bad).is_err(), "{bad}");
        }
        assert!(margin_mm("-5").is_err() && margin_mm("nan").is_err());
        assert_eq!(margin_mm("0").unwrap(), 0.0);
        assert!(coordinate_mm("nan").is_err() && coordinate_mm("1e308").is_err());
        assert_eq!(coordinate_mm("-12.5").unwrap(), -12.5);
        assert!(pyramid_levels("0").is_err() && pyramid_levels("64").is_err());
        assert_eq!(pyramid_levels("4").unwrap(), 4);
        assert!(patch_px("0").is_err() && patch_px("64").is_err() && patch_px("4097").is_err());
        assert_eq!(patch_px("65").unwrap(), 65);
    }
}
