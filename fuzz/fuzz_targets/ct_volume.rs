//! The CT readers: the first byte picks the reader, the rest is the file it reads: a phoenix
//! `.pcr` (beside a 6x6x6 16-bit `.vol`), a VGStudio `.vgi` (beside its raw file), a TIFF slice
//! of a stack, or a DICOM slice of a series (read as a CT and by `dicom info`).
#![no_main]

#[path = "scratch.rs"]
mod scratch;

use layerwise::ct::volume::{read_volume, VolumeSource};
use libfuzzer_sys::fuzz_target;

/// 6x6x6 little-endian u16 voxels, as the seeds' headers describe.
fn voxels() -> Vec<u8> {
    (0..216u16).flat_map(|i| i.to_le_bytes()).collect()
}

fuzz_target!(|data: &[u8]| {
    let Some((&kind, body)) = data.split_first() else {
        return;
    };
    match kind % 4 {
        0 => {
            scratch::file("pcr", "scan.vol", &voxels());
            let path = scratch::file("pcr", "scan.pcr", body);
            let _ = read_volume(&VolumeSource::Phoenix(path));
        }
        1 => {
            scratch::file("vgi", "scan.raw", &voxels());
            let path = scratch::file("vgi", "scan.vgi", body);
            let _ = read_volume(&VolumeSource::Vgi(path));
        }
        2 => {
            let path = scratch::file("tiff", "s000.tif", body);
            let dir = path.parent().expect("folder").to_path_buf();
            let _ = read_volume(&VolumeSource::Tiff(dir, 0.05));
        }
        _ => {
            let path = scratch::file("dicom", "slice.dcm", body);
            let dir = path.parent().expect("folder").to_path_buf();
            let _ = read_volume(&VolumeSource::Dicom(dir.clone()));
            let _ = layerwise::dicom::series_info(&dir);
        }
    }
});
