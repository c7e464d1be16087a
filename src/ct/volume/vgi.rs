//! VGStudio `.vgi` headers and the raw file they name.

use std::path::{Path, PathBuf};

use super::ini::Ini;
use super::raw::{read_raw, RawDtype, RawSpec};
use super::voxels::Volume;
use crate::ct::{CtError, Result};

/// Read a VGStudio `.vgi` and the raw file it names; at most `max_voxels` voxels.
pub fn read_vgi(path: &Path, max_voxels: usize) -> Result<Volume> {
    let (raw, spec) = vgi_spec(path)?;
    read_raw(&raw, &spec, max_voxels)
}

/// The raw file and layout a `.vgi` describes.
pub fn vgi_spec(path: &Path) -> Result<(PathBuf, RawSpec)> {
    let ini = Ini::read(path)?;
    let size = ini.numbers("file1", "Size", 3)?;
    if size
        .iter()
        .take(3)
        .any(|v| !(1.0..=1_048_576.0).contains(v) || v.fract() != 0.0)
    {
        return Err(ini.bad(
            "Size",
            ini.require("file1", "Size")?,
            "expected 3 positive integers of at most 1048576",
        ));
    }
    let dims = [size[0] as usize, size[1] as usize, size[2] as usize];
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
            // The raw file lies in the .vgi's folder: a relative path below it is followed, an
            // absolute path or one with `..` only by its file name (never outside the folder).
            let name = name.trim_matches('"').replace('\\', "/");
            let relative = Path::new(&name);
            let inside = relative
                .components()
                .all(|c| matches!(c, std::path::Component::Normal(_)));
            match relative.file_name() {
                _ if inside && dir.join(relative).is_file() => dir.join(relative),
                Some(file) => dir.join(file),
                None => return Err(ini.bad("Name", &name, "not a file name")),
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
        let vol = read_vgi(&d.join("scan.vgi"), crate::ct::volume::MAX_VOXELS).expect("read");
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

    #[test]
    fn a_vgi_name_never_leads_outside_its_folder() {
        let tmp = tempfile::tempdir().expect("tmp");
        let d = tmp.path().join("scan");
        std::fs::create_dir(&d).expect("dir");
        // A file the header must not reach: one level up.
        std::fs::write(tmp.path().join("secret.raw"), [0u8; 24]).expect("secret");
        std::fs::write(
            d.join("evil.vgi"),
            "{volume1}\n[file1]\nSize = 2 3 4\nName = ../secret.raw\nDatatype = unsigned integer\n\
             BitsPerElement = 8\n[geometry]\nresolution = 0.1\n",
        )
        .expect("vgi");
        let (raw, _) = vgi_spec(&d.join("evil.vgi")).expect("spec");
        assert_eq!(raw, d.join("secret.raw"), "confined to the .vgi's folder");
        assert!(read_vgi(&d.join("evil.vgi"), crate::ct::volume::MAX_VOXELS).is_err());
    }

    #[test]
    fn a_vgi_size_of_1e30_is_an_error_not_a_panic() {
        let tmp = tempfile::tempdir().expect("tmp");
        let d = tmp.path();
        std::fs::write(d.join("scan.raw"), [0u8; 8]).expect("raw");
        std::fs::write(
            d.join("big.vgi"),
            "{volume1}\n[file1]\nSize = 1e30 1 1\nName = scan.raw\nDatatype = unsigned integer\n\
             BitsPerElement = 8\n[geometry]\nresolution = 0.1\n",
        )
        .expect("vgi");
        let err = read_vgi(&d.join("big.vgi"), crate::ct::volume::MAX_VOXELS)
            .expect_err("refused")
            .to_string();
        assert!(err.contains("big.vgi") && err.contains("Size"), "{err}");
    }
}
