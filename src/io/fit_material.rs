//! The fit-material result file (`diffsound fit-material --out F.h5`): what other jobs read
//! from it. `format = "diffsound.fit_material"` at the root; `/material` carries the fitted
//! Young's modulus E (Pa), Poisson's ratio ν (1) and the density ρ (kg/m³) as attributes.

use super::results::{read_attribute, AttrValue};
use std::path::Path;

/// Reads E, ν, ρ from a fit-material result.
pub fn read_material(path: &Path) -> Result<(f64, f64, f64), String> {
    let number = |key: &str| -> Result<f64, String> {
        match read_attribute(path, "/material", key)
            .map_err(|e| format!("{}: {e}", path.display()))?
        {
            AttrValue::Number(v) => Ok(v),
            AttrValue::Text(t) => Err(format!(
                "{}: /material {key} is text {t:?}, expected a number",
                path.display()
            )),
        }
    };
    match read_attribute(path, "/", "format").map_err(|e| format!("{}: {e}", path.display()))? {
        AttrValue::Text(t) if t == "diffsound.fit_material" => {}
        other => {
            return Err(format!(
                "{} is not a fit-material result (format {other:?})",
                path.display()
            ))
        }
    }
    Ok((
        number("youngs_modulus")?,
        number("poisson_ratio")?,
        number("density")?,
    ))
}
