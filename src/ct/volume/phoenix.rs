//! GE phoenix volumes: a `.pcr` header beside the raw `.vol`.

use std::path::{Path, PathBuf};

use super::ini::Ini;
use super::raw::{read_raw, RawDtype, RawSpec};
use super::voxels::{Volume, VoxelData};
use crate::ct::{CtError, Result};

/// The `.vol` next to a `.pcr` (or the `.pcr` next to a `.vol`).
fn sibling(path: &Path, ext: &str) -> PathBuf {
    path.with_extension(ext)
}

/// Read a GE phoenix volume: `path` is the `.pcr` or the `.vol`; at most `max_voxels` voxels.
pub fn read_phoenix(path: &Path, max_voxels: usize) -> Result<Volume> {
    let is_pcr = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("pcr"));
    let (pcr, vol) = if is_pcr {
        (path.to_path_buf(), sibling(path, "vol"))
    } else {
        (sibling(path, "pcr"), path.to_path_buf())
    };
    let spec = phoenix_spec(&pcr)?;
    read_raw(&vol, &spec, max_voxels)
}

/// Writes `volume` as a GE phoenix volume: the `.pcr` header at `pcr` and the raw voxels in the
/// `.vol` beside it (little endian, physical = index × voxel size). u8, u16 and f32 voxels with
/// isotropic voxels only (what `.pcr` can describe); both files written atomically.
pub fn write_phoenix(pcr: &Path, volume: &Volume) -> Result<()> {
    let [vx, vy, vz] = volume.voxel_mm;
    if vx != vy || vx != vz {
        return Err(CtError::Invalid(format!(
            "{}: a .pcr holds one voxel size, the volume has {:?} mm",
            pcr.display(),
            volume.voxel_mm
        )));
    }
    let (format, bytes): (u8, Vec<u8>) = match &volume.data {
        VoxelData::U8(v) => (1, v.clone()),
        VoxelData::U16(v) => (5, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        VoxelData::F32(v) => (10, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        VoxelData::I16(_) => {
            return Err(CtError::Invalid(format!(
                "{}: a .pcr volume cannot hold signed 16-bit voxels",
                pcr.display()
            )))
        }
    };
    let [x, y, z] = volume.dims;
    let header = format!(
        "[VolumeData]\nVolume_SizeX={x}\nVolume_SizeY={y}\nVolume_SizeZ={z}\nVoxelSizeRec={vx}\nFormat={format}\n"
    );
    let vol = sibling(pcr, "vol");
    crate::fsutil::write_atomic_all(&[(&vol, &bytes), (pcr, header.as_bytes())], false).map_err(
        |e| CtError::Io {
            path: e.path,
            action: "write",
            source: e.source,
        },
    )
}

/// The raw layout described by a phoenix `.pcr`.
pub fn phoenix_spec(pcr: &Path) -> Result<RawSpec> {
    let ini = Ini::read(pcr)?;
    let s = "volumedata";
    let dims = [
        ini.number::<usize>(s, "Volume_SizeX")?,
        ini.number::<usize>(s, "Volume_SizeY")?,
        ini.number::<usize>(s, "Volume_SizeZ")?,
    ];
    let voxel: f64 = ini.number(s, "VoxelSizeRec")?;
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(ini.bad("VoxelSizeRec", &voxel.to_string(), "must be positive mm"));
    }
    let format = ini.require(s, "Format")?;
    let dtype = match format.trim() {
        "1" | "3" => RawDtype::U8,
        "5" => RawDtype::U16,
        "10" => RawDtype::F32,
        other => {
            return Err(CtError::UnknownDtype {
                path: pcr.to_path_buf(),
                dtype: format!("Format={other}"),
                expected: "Format 1 or 3 (8-bit), 5 (16-bit), 10 (float)",
            })
        }
    };
    if dims.contains(&0) {
        return Err(ini.bad("Volume_SizeX/Y/Z", &format!("{dims:?}"), "must be positive"));
    }
    Ok(RawSpec {
        dims,
        voxel_mm: [voxel; 3],
        dtype,
        header_bytes: 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ct::volume::tests::{scratch, write_u16};
    use crate::ct::volume::{VoxelData, MAX_VOXELS};

    #[test]
    fn phoenix_pcr_and_vol() {
        let d = scratch("pcr");
        let v = write_u16(&d.join("part.vol"), 4 * 3 * 2);
        std::fs::write(
            d.join("part.pcr"),
            "[General]\nVersion=2\n[VolumeData]\nVolume_SizeX=4\nVolume_SizeY=3\nVolume_SizeZ=2\n\
             Format=5\nVoxelSizeRec=0.0421\n",
        )
        .expect("pcr");
        for p in [d.join("part.pcr"), d.join("part.vol")] {
            let vol = read_phoenix(&p, crate::ct::volume::MAX_VOXELS).expect("read");
            assert_eq!(vol.dims, [4, 3, 2]);
            assert_eq!(vol.voxel_mm, [0.0421; 3]);
            assert_eq!(vol.data, VoxelData::U16(v.clone()));
            // x fastest: voxel (1, 2, 1) is element 1 + 4·2 + 12·1.
            assert_eq!(vol.value(1 + 4 * 2 + 12), v[21] as f64);
            assert_eq!(
                vol.index_to_physical([1.0, 2.0, 1.0]),
                [0.0421, 0.0842, 0.0421]
            );
        }
    }

    #[test]
    fn written_volumes_read_back() {
        let d = scratch("pcr-write");
        let data: Vec<u16> = (0..5 * 4 * 3).map(|i| (i * 1000) as u16).collect();
        let vol = Volume::new_scaled([5, 4, 3], [0.07; 3], VoxelData::U16(data)).expect("vol");
        write_phoenix(&d.join("ct.pcr"), &vol).expect("write");
        let back = read_phoenix(&d.join("ct.pcr"), MAX_VOXELS).expect("read");
        assert_eq!((back.dims, back.voxel_mm), (vol.dims, vol.voxel_mm));
        assert_eq!(back.data, vol.data);
        let anisotropic =
            Volume::new_scaled([1, 1, 1], [0.1, 0.1, 0.2], VoxelData::U8(vec![1])).expect("vol");
        let e = write_phoenix(&d.join("a.pcr"), &anisotropic).expect_err("one voxel size");
        assert!(e.to_string().contains("a.pcr"), "{e}");
    }

    #[test]
    fn raw_size_mismatch_names_expected_and_actual_bytes() {
        let d = scratch("mismatch");
        write_u16(&d.join("part.vol"), 20);
        std::fs::write(
            d.join("part.pcr"),
            "[VolumeData]\nVolume_SizeX=4\nVolume_SizeY=3\nVolume_SizeZ=2\nFormat=5\nVoxelSizeRec=0.05\n",
        )
        .expect("pcr");
        let e = read_phoenix(&d.join("part.pcr"), crate::ct::volume::MAX_VOXELS)
            .expect_err("short file");
        let msg = e.to_string();
        assert!(msg.contains("part.vol"), "{msg}");
        assert!(
            msg.contains("is 40 bytes") && msg.contains("need 48 bytes"),
            "{msg}"
        );
    }

    #[test]
    fn pcr_missing_key_and_unknown_format() {
        let d = scratch("pcrkeys");
        std::fs::write(
            d.join("a.pcr"),
            "[VolumeData]\nVolume_SizeX=4\nVolume_SizeY=3\nFormat=5\nVoxelSizeRec=0.05\n",
        )
        .expect("pcr");
        let msg = phoenix_spec(&d.join("a.pcr"))
            .expect_err("no Z")
            .to_string();
        assert!(
            msg.contains("a.pcr") && msg.contains("Volume_SizeZ"),
            "{msg}"
        );
        std::fs::write(
            d.join("b.pcr"),
            "[VolumeData]\nVolume_SizeX=4\nVolume_SizeY=3\nVolume_SizeZ=2\nFormat=7\nVoxelSizeRec=0.05\n",
        )
        .expect("pcr");
        let e = phoenix_spec(&d.join("b.pcr")).expect_err("format 7");
        assert!(matches!(e, CtError::UnknownDtype { .. }), "{e}");
        assert!(e.to_string().contains("Format=7"), "{e}");
    }
}
