//! VGStudio `.vgi` headers and the raw file they name.

use std::path::{Path, PathBuf};

use super::ini::Ini;
use super::{read_raw, CtError, RawDtype, RawSpec, Result, Volume};

/// Read a VGStudio `.vgi` and the raw file it names.
pub fn read_vgi(path: &Path) -> Result<Volume> {
    let (raw, spec) = vgi_spec(path)?;
    read_raw(&raw, &spec)
}

/// The raw file and layout a `.vgi` describes.
pub fn vgi_spec(path: &Path) -> Result<(PathBuf, RawSpec)> {
    let ini = Ini::read(path)?;
    let size = ini.numbers("file1", "Size", 3)?;
    let dims = [size[0] as usize, size[1] as usize, size[2] as usize];
    if size.iter().take(3).any(|v| *v < 1.0 || v.fract() != 0.0) {
        return Err(ini.bad(
            "Size",
            ini.require("file1", "Size")?,
            "expected 3 positive integers",
        ));
    }
    let res = ini.numbers("geometry", "resolution", 1)?;
    let voxel_mm = if res.len() >= 3 {
        [res[0], res[1], res[2]]
    } else {
        [res[0]; 3]
    };
    if voxel_mm.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(ini.bad("resolution", &format!("{res:?}"), "must be positive mm"));
    }
    let dt = ini.require("file1", "Datatype")?.to_ascii_lowercase();
    let bits: u32 = ini.number("file1", "BitsPerElement")?;
    let float = dt.contains("float") || dt.contains("real");
    let signed = dt.contains("signed") && !dt.contains("unsigned");
    let dtype = match (float, signed, bits) {
        (true, _, 32) => RawDtype::F32,
        (false, false, 8) => RawDtype::U8,
        (false, false, 16) => RawDtype::U16,
        (false, true, 16) => RawDtype::I16,
        _ => {
            return Err(CtError::UnknownDtype {
                path: path.to_path_buf(),
                dtype: format!("Datatype={dt}, BitsPerElement={bits}"),
                expected: "unsigned 8/16-bit, signed 16-bit or 32-bit float",
            })
        }
    };
    let header_bytes = match ini.get("file1", "SkipHeader") {
        Some(v) => v
            .parse()
            .map_err(|_| ini.bad("SkipHeader", v, "not a byte count"))?,
        None => 0,
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let raw = match ini.get("file1", "Name") {
        // The name is relative to the .vgi, possibly written with Windows separators.
        Some(name) => {
            let name = name.trim_matches('"').replace('\\', "/");
            let file = Path::new(&name).file_name().map(PathBuf::from);
            let direct = dir.join(&name);
            match file {
                Some(f) if !direct.exists() => dir.join(f),
                _ => direct,
            }
        }
        None => {
            let vol = path.with_extension("vol");
            if vol.exists() {
                vol
            } else {
                path.with_extension("raw")
            }
        }
    };
    Ok((
        raw,
        RawSpec {
            dims,
            voxel_mm,
            dtype,
            header_bytes,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ct::volume::tests::scratch;

    #[test]
    fn vgi_with_named_raw_file() {
        let d = scratch("vgi");
        let bytes: Vec<u8> = (0..24u32)
            .flat_map(|i| (i as f32 * 0.5).to_le_bytes())
            .collect();
        std::fs::write(d.join("scan.raw"), bytes).expect("raw");
        std::fs::write(
            d.join("scan.vgi"),
            "{volume1}\n[representation]\nsize = 4 3 2\n[file1]\nSkipHeader = 0\nFileFormat = raw\n\
             Size = 4 3 2\nName = C:\\data\\scan.raw\nDatatype = float\nBitsPerElement = 32\n\
             [geometry]\nstatus = ok\nresolution = 0.03 0.03 0.04\nunit = mm\n",
        )
        .expect("vgi");
        let vol = read_vgi(&d.join("scan.vgi")).expect("read");
        assert_eq!(vol.dims, [4, 3, 2]);
        assert_eq!(vol.voxel_mm, [0.03, 0.03, 0.04]);
        assert_eq!(vol.value(23), 11.5);
        std::fs::write(
            d.join("bad.vgi"),
            "[file1]\nSize = 4 3 2\nDatatype = complex\nBitsPerElement = 64\n[geometry]\nresolution = 0.03\n",
        )
        .expect("vgi");
        let e = vgi_spec(&d.join("bad.vgi")).expect_err("complex");
        assert!(matches!(e, CtError::UnknownDtype { .. }), "{e}");
    }
}
