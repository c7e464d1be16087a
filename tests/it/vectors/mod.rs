//! Tests of the CLI vector reader/writer against the real files in shared/data/cli and against
//! generated and deliberately broken input.

use crate::common;
use crate::common::{shared_cli, Rng, VECTORS_INFO_KEYS};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod broken;

use layerwise::vectors::{
    self, synth, Direction, Format, Info, LayerIndex, LayerReader, MarkingParameter, VectorError,
    VectorFile,
};

const FILES: [&str; 4] = common::REAL_CLI_FILES;

fn bytes_of(name: &str) -> Vec<u8> {
    std::fs::read(shared_cli(name)).unwrap()
}

/// A scratch file path unique to this process and test.
struct TempFile(PathBuf);

impl TempFile {
    fn new(tag: &str) -> TempFile {
        TempFile(std::env::temp_dir().join(format!(
            "layerwise-vectors-{}-{tag}.cli",
            std::process::id()
        )))
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// x/y extent of all geometry and z range of the layers that have geometry.
fn extent(f: &VectorFile) -> ([f64; 4], [f64; 2]) {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let mut z = [f64::INFINITY, f64::NEG_INFINITY];
    let mut add = |x: f64, y: f64| {
        b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
    };
    for l in &f.layers {
        for p in &l.polylines {
            for &[x, y] in &p.points {
                add(x, y);
            }
        }
        for h in &l.hatches {
            for &[sx, sy, ex, ey] in &h.segments {
                add(sx, sy);
                add(ex, ey);
            }
        }
        if !l.polylines.is_empty() || !l.hatches.is_empty() {
            z = [z[0].min(l.z_mm), z[1].max(l.z_mm)];
        }
    }
    (b, z)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

/// Asserts two files have the same layers, geometry within `tol(value)`, and (optionally) the
/// same marking parameters.
fn assert_same_geometry(a: &VectorFile, b: &VectorFile, tol: impl Fn(f64) -> f64, params: bool) {
    assert_eq!(a.layers.len(), b.layers.len(), "layer count");
    for (la, lb) in a.layers.iter().zip(&b.layers) {
        let same_coordinates = |p: &[f64], q: &[f64]| {
            for (u, v) in p.iter().zip(q) {
                assert!(close(*u, *v, tol(*u)), "layer {}: {u} vs {v}", la.index);
            }
        };
        assert_eq!(la.index, lb.index);
        assert!(
            close(la.z_mm, lb.z_mm, tol(la.z_mm)),
            "z {} vs {}",
            la.z_mm,
            lb.z_mm
        );
        assert_eq!(
            la.polylines.len(),
            lb.polylines.len(),
            "polylines in layer {}",
            la.index
        );
        for (pa, pb) in la.polylines.iter().zip(&lb.polylines) {
            assert_eq!(pa.part, pb.part);
            assert_eq!(pa.direction, pb.direction);
            assert_eq!(pa.points.len(), pb.points.len());
            for (qa, qb) in pa.points.iter().zip(&pb.points) {
                same_coordinates(qa, qb);
            }
        }
        assert_eq!(
            la.hatches.len(),
            lb.hatches.len(),
            "hatches in layer {}",
            la.index
        );
        for (ha, hb) in la.hatches.iter().zip(&lb.hatches) {
            assert_eq!(ha.part, hb.part);
            assert_eq!(ha.segments.len(), hb.segments.len());
            for (sa, sb) in ha.segments.iter().zip(&hb.segments) {
                same_coordinates(sa, sb);
            }
        }
        if params {
            assert_eq!(
                la.parameters, lb.parameters,
                "parameters of layer {}",
                la.index
            );
        }
    }
}

const ASCII_TOL: fn(f64) -> f64 = |_| 1e-6;
/// Relative precision of a f32 (2^-23) plus a little.
const F32_TOL: fn(f64) -> f64 = |v| v.abs() * 1.2e-7 + 1e-12;

fn ascii_bytes(f: &VectorFile) -> Vec<u8> {
    let mut out = Vec::new();
    vectors::write_ascii(f, &mut out).unwrap();
    out
}

fn binary_bytes(f: &VectorFile) -> Vec<u8> {
    let mut out = Vec::new();
    vectors::write_binary(f, &mut out).unwrap();
    out
}

// ---------------------------------------------------------------------------------------------
// Real files

#[test]
fn real_files_agree_with_their_own_header() {
    for name in FILES {
        let path = shared_cli(name);
        let f = vectors::read(&path).unwrap_or_else(|e| panic!("{e}"));
        let h = &f.header;
        let declared = h.layers_declared.expect("$$LAYERS");
        assert_eq!(
            f.layers.len(),
            declared as usize,
            "{name}: layers vs $$LAYERS"
        );
        for (k, l) in f.layers.iter().enumerate() {
            assert_eq!(l.index, k);
        }
        // $$DIMENSION is in millimetres in these files; allow one unit (the short coordinates
        // are rounded to whole units while the dimension is not).
        let [x1, y1, z1, x2, y2, z2] = h.dimension_mm.expect("$$DIMENSION");
        let unit = h.units_mm + 1e-9;
        let ([gx1, gy1, gx2, gy2], [gz1, gz2]) = extent(&f);
        assert!(
            gx1 >= x1 - unit && gx2 <= x2 + unit,
            "{name}: x {gx1}..{gx2} vs {x1}..{x2}"
        );
        assert!(
            gy1 >= y1 - unit && gy2 <= y2 + unit,
            "{name}: y {gy1}..{gy2} vs {y1}..{y2}"
        );
        // The geometry also fills the declared box (it is not a loose bound).
        assert!(
            close(gx1, x1, unit) && close(gx2, x2, unit),
            "{name}: x extent"
        );
        assert!(
            close(gy1, y1, unit) && close(gy2, y2, unit),
            "{name}: y extent"
        );
        // z: the declared range is that of the layers carrying geometry (the Box file has empty
        // layers from z=0 to 3.0 and one at 30.33 outside its $$DIMENSION 3.03..30.3).
        assert!(close(gz1, z1, unit), "{name}: z min {gz1} vs {z1}");
        assert!(close(gz2, z2, unit), "{name}: z max {gz2} vs {z2}");

        let info = vectors::info(&path).unwrap();
        assert_eq!(
            info,
            Info::of(&f),
            "{name}: streaming info vs in-memory info"
        );
        assert_eq!(info.layers, declared as usize);
        assert_eq!(info.declared_layers, Some(declared));
        assert_eq!(info.declared_dimension_mm, h.dimension_mm);
        let [bx1, by1, bz1, bx2, by2, bz2] = info.bbox_mm.unwrap();
        assert_eq!([bx1, by1, bx2, by2], [gx1, gy1, gx2, gy2]);
        assert_eq!([bz1, bz2], [gz1, gz2]);
    }
}

#[test]
fn cylinder_is_binary_with_signed_short_coordinates() {
    let f = vectors::read(&shared_cli("s_Cylinder_ex.cli")).unwrap();
    assert_eq!(f.header.format, Format::Binary);
    assert_eq!(f.header.units_mm, 0.01);
    assert_eq!(f.header.version.as_deref(), Some("200"));
    assert_eq!(f.header.date.as_deref(), Some("230819"));
    assert_eq!(f.header.labels, vec![(1, "part1".to_string())]);
    let dim = f.header.dimension_mm.unwrap();
    assert_eq!(dim, [-4.9387, -15.9386, 0.0, 4.9407, -6.0588, 1.05]);
    let z: Vec<f64> = f.layers.iter().map(|l| l.z_mm).collect();
    let want: Vec<f64> = (0..8).map(|k| f64::from(k * 15) * 0.01).collect();
    assert_eq!(z, want);
    // First polyline: bytes e1 fe 3d fa = (-287, -1475) units.
    let p = &f.layers[0].polylines[0];
    assert_eq!(p.part, 1);
    assert_eq!(p.direction, Direction::CounterClockwise);
    assert_eq!(p.points.len(), 69);
    assert_eq!(p.points[0], [-287.0 * 0.01, -1475.0 * 0.01]);
    let ([x1, y1, x2, y2], _) = extent(&f);
    assert!(
        x1 < 0.0 && x2 > 0.0 && y1 < 0.0 && y2 < 0.0,
        "{x1} {y1} {x2} {y2}"
    );
}

#[test]
fn minicooper_reads() {
    let f = vectors::read(&shared_cli("s_MiniCooper_ex.cli")).unwrap();
    assert_eq!(f.header.format, Format::Binary);
    assert_eq!(f.layers.len(), 27);
    let polylines: usize = f.layers.iter().map(|l| l.polylines.len()).sum();
    assert_eq!(polylines, 1593);
    assert!((f.layers[26].z_mm - 3.9).abs() < 1e-12);
}

#[test]
fn frustrum_ascii_zero_padded_header() {
    let f = vectors::read(&shared_cli("frustrum_ASCII.cli")).unwrap();
    let h = &f.header;
    assert_eq!(h.format, Format::Ascii);
    assert_eq!(h.units_mm, 0.005);
    assert_eq!(h.layers_declared, Some(100));
    assert_eq!(h.date.as_deref(), Some("170921"));
    assert_eq!(h.dimension_mm.unwrap()[3], 19.920006);
    assert_eq!(f.layers.len(), 100);
    assert!((f.layers[0].z_mm - 0.1).abs() < 1e-12);
    let h0 = &f.layers[0].hatches[0];
    assert_eq!(h0.segments.len(), 39);
    let s = h0.segments[0];
    let want = [263.60483, 1009.18732, 1020.80188, 251.99030].map(|v| v * 0.005);
    for (a, b) in s.iter().zip(want) {
        assert!((a - b).abs() < 1e-12);
    }
    let info = vectors::info(&shared_cli("frustrum_ASCII.cli")).unwrap();
    assert_eq!(info.hatches, 3181, "hatch segments, not hatch commands");
    assert_eq!(info.polylines, 100);
    assert_eq!(info.points, 2513);
    assert_eq!(info.layer_thickness, Some(0.1));
}

#[test]
fn box_cli_plus_parameters_date_and_empty_layers() {
    let path = shared_cli("Box_support_solid_ascii_with_params.cli");
    let f = vectors::read(&path).unwrap();
    assert_eq!(f.header.date.as_deref(), Some("20240702"));
    assert_eq!(f.header.units_mm, 0.001);
    assert_eq!(f.layers.len(), 1012);
    let empty = f.layers.iter().filter(|l| l.is_empty()).count();
    assert_eq!(empty, 102);
    assert!(f.layers[0].is_empty() && f.layers[0].z_mm == 0.0);
    assert!(f.layers[1011].is_empty());
    let first = f.layers.iter().position(|l| !l.is_empty()).unwrap();
    assert_eq!(first, 101);
    assert!((f.layers[first].z_mm - 3.03).abs() < 1e-12);
    assert_eq!(
        f.layers[first].parameters,
        vec![
            MarkingParameter::Power(100.0),
            MarkingParameter::Speed(200.0),
            MarkingParameter::Focus(1.0)
        ]
    );
    assert_eq!(
        f.layers[first + 3].parameters,
        vec![MarkingParameter::Power(150.0)]
    );
    assert_eq!(
        f.layers[first + 4].parameters,
        vec![
            MarkingParameter::Power(100.0),
            MarkingParameter::Speed(100.0)
        ]
    );
    let total: usize = f.layers.iter().map(|l| l.parameters.len()).sum();
    assert_eq!(total, 6);
    assert_eq!(f.layers[first].polylines[0].direction, Direction::Open);
    let info = vectors::info(&path).unwrap();
    assert_eq!(info.empty_layers, 102);
    assert_eq!(info.parameters, 6);
    assert_eq!(info.layer_thickness, Some(0.03));
    assert_eq!(info.z_min, Some(0.0));
}

// ---------------------------------------------------------------------------------------------
// Round trips

#[test]
fn generated_file_round_trips_through_ascii_within_a_nanometre() {
    let f = synth::generate(6, 40, 36);
    let text = ascii_bytes(&f);
    let back = vectors::read_bytes(&text, "gen.cli").unwrap();
    assert_eq!(back.header.format, Format::Ascii);
    assert_eq!(back.header.units_mm, f.header.units_mm);
    assert_eq!(back.header.labels, f.header.labels);
    assert_eq!(back.header.date, f.header.date);
    assert_eq!(back.header.version, f.header.version);
    assert_eq!(back.header.dimension_mm, f.header.dimension_mm);
    assert_eq!(back.header.layers_declared, Some(6));
    assert_same_geometry(&f, &back, ASCII_TOL, true);
    // The contours are closed circles, outer counter-clockwise and inner clockwise.
    let l = &back.layers[0];
    assert_eq!(l.polylines[0].direction, Direction::CounterClockwise);
    assert_eq!(l.polylines[1].direction, Direction::Clockwise);
    assert_eq!(l.polylines[0].points.first(), l.polylines[0].points.last());
    // Writing what was read gives the same text.
    assert_eq!(ascii_bytes(&back), text);
}

#[test]
fn generated_file_round_trips_through_binary_within_f32_precision() {
    let f = synth::generate(6, 40, 36);
    let bin = binary_bytes(&f);
    let back = vectors::read_bytes(&bin, "gen.cli").unwrap();
    assert_eq!(back.header.format, Format::Binary);
    assert_eq!(back.header.labels, f.header.labels);
    assert_same_geometry(&f, &back, F32_TOL, false);
    // Binary CLI has no marking parameters.
    assert!(back.layers.iter().all(|l| l.parameters.is_empty()));
    // Binary to binary is exact.
    assert_eq!(binary_bytes(&back), bin);
}

#[test]
fn real_files_round_trip_through_both_writers() {
    for name in FILES {
        let f = vectors::read(&shared_cli(name)).unwrap();
        let a = vectors::read_bytes(&ascii_bytes(&f), name).unwrap();
        assert_eq!(a.header.units_mm, f.header.units_mm);
        assert_eq!(a.header.labels, f.header.labels);
        assert_eq!(a.header.dimension_mm, f.header.dimension_mm);
        assert_eq!(a.header.date, f.header.date);
        assert_same_geometry(&f, &a, ASCII_TOL, true);
        assert_eq!(Info::of(&a).points, Info::of(&f).points);

        let b = vectors::read_bytes(&binary_bytes(&f), name).unwrap();
        assert_eq!(b.header.format, Format::Binary);
        assert_same_geometry(&f, &b, F32_TOL, false);
        let (ib, ia) = (Info::of(&b), Info::of(&f));
        assert_eq!(
            (ib.layers, ib.polylines, ib.points, ib.hatches),
            (ia.layers, ia.polylines, ia.points, ia.hatches),
            "{name}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Streaming and random access

fn check_stream_and_index(path: &Path) {
    let all = vectors::read(path).unwrap();
    let mut reader = LayerReader::open(path).unwrap();
    assert_eq!(reader.header(), &all.header);
    let mut streamed = Vec::new();
    while let Some(l) = reader.next_layer().unwrap() {
        streamed.push(l);
    }
    assert!(reader.next_layer().unwrap().is_none());
    assert_eq!(streamed, all.layers, "{}", path.display());

    let index = LayerIndex::build(path).unwrap();
    assert_eq!(index.len(), all.layers.len());
    assert_eq!(index.header(), &all.header);
    for (k, layer) in all.layers.iter().enumerate() {
        assert_eq!(index.z_mm(k), Some(layer.z_mm));
        assert_eq!(
            &index.read_layer(k).unwrap(),
            layer,
            "{} layer {k}",
            path.display()
        );
    }
    assert_eq!(index.z_mm(index.len()), None);
    let e = index.read_layer(index.len()).unwrap_err();
    assert!(matches!(e, VectorError::NoSuchLayer { .. }), "{e}");
}

#[test]
fn streaming_and_index_match_read_on_real_files() {
    for name in FILES {
        check_stream_and_index(&shared_cli(name));
    }
}

#[test]
fn streaming_and_index_match_read_on_files_larger_than_the_buffer() {
    // About 1 MB each, so records and lines straddle the 256 KiB read buffer.
    let f = synth::generate(20, 2500, 50);
    let bin = TempFile::new("stream-bin");
    std::fs::write(&bin.0, binary_bytes(&f)).unwrap();
    check_stream_and_index(&bin.0);
    let txt = TempFile::new("stream-ascii");
    std::fs::write(&txt.0, ascii_bytes(&f)).unwrap();
    check_stream_and_index(&txt.0);
    assert!(std::fs::metadata(&bin.0).unwrap().len() > 600_000);
}

#[test]
fn layer_reader_is_an_iterator_and_stops_after_an_error() {
    let mut bytes = bytes_of("s_Cylinder_ex.cli");
    bytes.truncate(bytes.len() - 3);
    let tmp = TempFile::new("iter-cut");
    std::fs::write(&tmp.0, &bytes).unwrap();
    let results: Vec<_> = LayerReader::open(&tmp.0).unwrap().collect();
    assert_eq!(results.len(), 8, "7 layers and then the error");
    assert!(results[..7].iter().all(Result::is_ok));
    let e = results[7].as_ref().unwrap_err();
    assert!(
        e.to_string().contains("truncated $$POLYLINE (command 129)"),
        "{e}"
    );
}
